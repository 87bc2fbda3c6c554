"""A period-shifted copy of a plane: on a periodic planar texture (a chessboard, a grid of
windows) matches off by one period follow a second homography; the final plane check must not
count them as parallax (:func:`shifted_plane_copy`)."""

from __future__ import annotations

import numba
import numpy as np

from sepfm_ros.geometry.fundamental.degeneracy import robust_homography, transfer_error

__all__ = ["nearest_within", "shifted_plane_copy"]


@numba.njit(cache=True, nogil=True)
def nearest_within(points: np.ndarray, queries: np.ndarray, radius: float) -> np.ndarray:
    """(M,) distance (px) from each of ``queries`` (M, 2) to its nearest of ``points`` (N, 2)
    when it is below ``radius``, else inf (a grid of ``radius`` cells, sorted by cell, searched in
    the 3 x 3 cells around each query)."""
    n, m = points.shape[0], queries.shape[0]
    out = np.full(m, np.inf)
    if n == 0 or m == 0 or not radius > 0.0:
        return out
    x0 = points[:, 0].min()
    y0 = points[:, 1].min()
    rows = np.int64((points[:, 1].max() - y0) / radius) + 3
    cols = np.int64((points[:, 0].max() - x0) / radius) + 3
    keys = np.empty(n, dtype=np.int64)
    for i in range(n):
        cx = np.int64((points[i, 0] - x0) / radius) + 1
        cy = np.int64((points[i, 1] - y0) / radius) + 1
        keys[i] = cx * rows + cy
    order = np.argsort(keys)
    sorted_keys = keys[order]
    r2 = radius * radius
    for j in range(m):
        qx, qy = queries[j, 0], queries[j, 1]
        fx, fy = (qx - x0) / radius, (qy - y0) / radius
        if not (-2.0 < fx < cols and -2.0 < fy < rows):  # no point within radius (or NaN)
            continue
        cx = np.int64(np.floor(fx)) + 1
        cy = np.int64(np.floor(fy)) + 1
        best = r2
        lo, hi = max(cy - 1, 0), min(cy + 1, rows - 1)
        for dx in range(-1, 2):  # the cells (cx + dx, lo .. hi) have consecutive keys
            first = (cx + dx) * rows
            k = np.searchsorted(sorted_keys, first + lo)
            while k < n and sorted_keys[k] <= first + hi:
                i = order[k]
                ex, ey = points[i, 0] - qx, points[i, 1] - qy
                d2 = ex * ex + ey * ey
                if d2 < best:
                    best = d2
                k += 1
        if best < r2:
            out[j] = np.sqrt(best)
    return out


def shifted_plane_copy(
    H: np.ndarray,
    pts1: np.ndarray,
    pts2: np.ndarray,
    candidates: np.ndarray,
    tol: float,
    rng: np.random.Generator,
    min_share: float = 0.5,
    min_points: int = 8,
    min_self_share: float = 0.3,
    rel: float = 0.15,
    max_fit: int = 300,
    max_iterations: int = 500,
    transfer: np.ndarray | None = None,
) -> np.ndarray | None:
    """Matches that follow the plane H shifted by one period of a periodic texture on it.

    On a periodic planar texture (a chessboard, a facade's grid of windows) matches off by one
    period follow a second homography H2 = H S (S: the texture's period shift in the plane).
    They lie far from H, so a plane-and-parallax check counts them as parallax; but they carry
    no information about F beyond the plane: an F with its epipole at the vanishing point of
    the shift explains both sets. Such an H2 is recognised by what the shift does in image 2:
    M = H2 H^-1 maps the plane's own points onto other points of the plane (a period), while the
    homography of a real second plane maps them to arbitrary places.

    Args:
        H: (3, 3) the plane's homography, image 1 -> image 2.
        pts1, pts2: (N, 2) all matches, px.
        candidates: (N,) bool, the matches to test (e.g. inliers of F far from H).
        tol: px, homography transfer tolerance (also the hit tolerance of M).
        rng: seeds OpenCV's RANSAC for H2.
        min_share: H2 must explain this share of the candidates (and ``min_points``).
        min_self_share: M must map this share of the points on H onto another of them (in
            image 2, within min(``tol``, ``rel`` times the point's shift)), and three times as
            many as land that close to uniform random points of the plane's bounding box
            (chance: with a large ``tol`` every point of a dense plane is near another).
        max_fit: most candidates H2 is searched on (a random subset; it is scored on all).
        max_iterations: cap on the RHO samples of the H2 search (F(4, 1 - min_share) at 0.995
            below it).
        transfer: (N,) px, ``transfer_error(H, pts1, pts2)`` when the caller has it.
    Returns:
        (N,) bool, the candidates on the shifted copy H2, or None when there is none.
    """
    idx = np.flatnonzero(candidates)
    if len(idx) < min_points:
        return None
    n_candidates = len(idx)
    if len(idx) > max_fit:  # H2 is searched on a random subset (scored on all candidates)
        idx = np.sort(rng.choice(idx, max_fit, replace=False))
    seed = int(rng.integers(0, 2**31 - 1))
    H2 = robust_homography(pts1[idx], pts2[idx], tol, min_share, seed, max_iterations)
    if H2 is None:
        return None
    on2 = candidates & (transfer_error(H2, pts1, pts2) < tol)
    k = int(np.count_nonzero(on2))
    if k < max(min_points, min_share * n_candidates):
        return None
    if transfer is None:
        transfer = transfer_error(H, pts1, pts2)
    plane = pts2[transfer < tol]
    if len(plane) < min_points:
        return None
    try:
        M = H2 @ np.linalg.inv(H)
    except np.linalg.LinAlgError:
        return None
    y = np.c_[plane, np.ones(len(plane))] @ M.T
    with np.errstate(divide="ignore", invalid="ignore"):
        y = y[:, :2] / y[:, 2:]
    finite = np.isfinite(y).all(axis=1)
    shift = np.linalg.norm(y[finite] - plane[finite], axis=1)
    radius = np.minimum(tol, rel * shift)  # px, relative to the shift as in the 1D test
    near = nearest_within(plane, np.ascontiguousarray(y[finite]), float(tol))
    hits = np.count_nonzero((shift > tol) & (near < radius))
    # chance: the same radii around uniform points in the plane's bounding box
    probe = rng.uniform(plane.min(axis=0), plane.max(axis=0), (len(radius), 2))
    near_probe = nearest_within(plane, probe, float(tol))
    chance = np.count_nonzero(near_probe < radius)
    if hits < max(min_self_share * len(plane), 3.0 * chance):
        return None
    return on2
