"""A period-shifted copy of a plane: on a periodic planar texture (a chessboard, a grid of
windows) matches off by one period follow a second homography; the final plane check must not
count them as parallax (:func:`shifted_plane_copy`)."""

from __future__ import annotations

import numba
import numpy as np

from sepfm_ros.geometry.fundamental.degeneracy import robust_homography, transfer_error

__all__ = ["cell_grid", "grid_nearest", "nearest_within", "shifted_plane_copy"]


#: a :func:`cell_grid`: (lo, hi, side, rows, cols, start, order)
Grid = tuple[np.ndarray, np.ndarray, float, int, int, np.ndarray, np.ndarray]


@numba.njit(cache=True, nogil=True)
def cell_grid(points: np.ndarray, radius: float) -> Grid:
    """Square cells over ``points`` (N >= 1, 2) for searches within ``radius`` (px, > 0).

    The cells' side is at least ``radius`` (so a point within it of a query lies in the 3 x 3
    cells around the query's), and about the spacing of the points spread over their bounding
    box (so a cell holds about one; at most 4096 cells a side).

    Returns:
        (lo (2,), hi (2,) the points' bounding box, px; side, px; rows, cols; start
        (rows * cols + 1,) where each cell's points begin in ``order``; order (N,) point indices
        by cell, cell ``c * rows + r`` for column c, row r).
    """
    n = points.shape[0]
    lo = np.empty(2)
    hi = np.empty(2)
    for a in range(2):
        lo[a] = points[:, a].min()
        hi[a] = points[:, a].max()
    w, h = hi[0] - lo[0], hi[1] - lo[1]
    side = max(radius, np.sqrt(w * h / n), max(w, h) / 4096.0)
    cols = np.int64(w / side) + 3
    rows = np.int64(h / side) + 3
    start = np.zeros(rows * cols + 1, dtype=np.int64)
    keys = np.empty(n, dtype=np.int64)
    for i in range(n):
        cx = np.int64((points[i, 0] - lo[0]) / side) + 1
        cy = np.int64((points[i, 1] - lo[1]) / side) + 1
        keys[i] = cx * rows + cy
        start[keys[i] + 1] += 1
    for c in range(rows * cols):
        start[c + 1] += start[c]
    fill = start[:-1].copy()
    order = np.empty(n, dtype=np.int64)
    for i in range(n):
        order[fill[keys[i]]] = i
        fill[keys[i]] += 1
    return lo, hi, side, rows, cols, start, order


@numba.njit(cache=True, nogil=True)
def grid_nearest(
    points: np.ndarray,
    grid: Grid,
    queries: np.ndarray,
    radius: float,
) -> np.ndarray:
    """(M,) distance (px) from each of ``queries`` (M, 2) to its nearest of ``points`` (N, 2)
    when it is below ``radius``, else inf; ``grid`` is ``cell_grid(points, r)`` for an
    r >= ``radius``."""
    lo, _, side, rows, cols, start, order = grid
    m = queries.shape[0]
    out = np.full(m, np.inf)
    r2 = radius * radius
    for j in range(m):
        qx, qy = queries[j, 0], queries[j, 1]
        fx, fy = (qx - lo[0]) / side, (qy - lo[1]) / side
        if not (-2.0 < fx < cols and -2.0 < fy < rows):  # no point within radius (or NaN)
            continue
        cx = np.int64(np.floor(fx)) + 1
        cy = np.int64(np.floor(fy)) + 1
        best = r2
        r0, r1 = max(cy - 1, 0), min(cy + 1, rows - 1)
        for c in range(max(cx - 1, 0), min(cx + 1, cols - 1) + 1):
            # the cells (c, r0 .. r1) are consecutive in ``order``
            for k in range(start[c * rows + r0], start[c * rows + r1 + 1]):
                i = order[k]
                ex, ey = points[i, 0] - qx, points[i, 1] - qy
                d2 = ex * ex + ey * ey
                if d2 < best:
                    best = d2
        if best < r2:
            out[j] = np.sqrt(best)
    return out


@numba.njit(cache=True, nogil=True)
def nearest_within(points: np.ndarray, queries: np.ndarray, radius: float) -> np.ndarray:
    """(M,) distance (px) from each of ``queries`` (M, 2) to its nearest of ``points`` (N, 2)
    when it is below ``radius``, else inf (a :func:`cell_grid` searched in the 3 x 3 cells
    around each query)."""
    if points.shape[0] == 0 or queries.shape[0] == 0 or not radius > 0.0:
        return np.full(queries.shape[0], np.inf)
    return grid_nearest(points, cell_grid(points, radius), queries, radius)


@numba.njit(cache=True, nogil=True)
def period_hits(
    plane: np.ndarray,
    H: np.ndarray,
    H2: np.ndarray,
    grid: Grid,
    tol: float,
    rel: float,
) -> tuple[int, np.ndarray]:
    """How many of the ``plane`` points (N, 2, image 2, px) the shift M = H2 H^-1 (H, H2: (3, 3)
    homographies image 1 -> 2) maps onto another of them: moved by more than ``tol`` px and
    landing within min(``tol``, ``rel`` times the move) of one (``grid``: ``cell_grid(plane,
    tol)``). Returns (hits, radius (K,) px: that hit radius of each of the K points whose image
    is finite); hits is -1 when H is singular."""
    # H^-1 up to the scale det(H) (its rows: cross products of H's columns); M maps points,
    # so its scale does not matter
    adj = np.empty((3, 3))
    for r in range(3):
        a, b = (r + 1) % 3, (r + 2) % 3
        adj[r, 0] = H[1, a] * H[2, b] - H[2, a] * H[1, b]
        adj[r, 1] = H[2, a] * H[0, b] - H[0, a] * H[2, b]
        adj[r, 2] = H[0, a] * H[1, b] - H[1, a] * H[0, b]
    det = H[0, 0] * adj[0, 0] + H[1, 0] * adj[0, 1] + H[2, 0] * adj[0, 2]
    if det == 0.0 or not np.isfinite(det) or not np.isfinite(adj).all():
        return -1, np.empty(0)
    M = np.zeros((3, 3))
    for r in range(3):
        for c in range(3):
            for k in range(3):
                M[r, c] += H2[r, k] * adj[k, c]
    n = plane.shape[0]
    moved = np.empty((n, 2))
    shift = np.empty(n)
    k = 0
    for i in range(n):
        x, y = plane[i, 0], plane[i, 1]
        w = M[2, 0] * x + M[2, 1] * y + M[2, 2]
        u = (M[0, 0] * x + M[0, 1] * y + M[0, 2]) / w
        v = (M[1, 0] * x + M[1, 1] * y + M[1, 2]) / w
        if np.isfinite(u) and np.isfinite(v):
            moved[k, 0], moved[k, 1] = u, v
            du, dv = u - x, v - y
            shift[k] = np.sqrt(du * du + dv * dv)
            k += 1
    near = grid_nearest(plane, grid, moved[:k], tol)
    radius = np.empty(k)
    hits = 0
    for i in range(k):
        radius[i] = min(tol, rel * shift[i])
        if shift[i] > tol and near[i] < radius[i]:
            hits += 1
    return hits, radius


@numba.njit(cache=True, nogil=True)
def count_near(
    plane: np.ndarray,
    grid: Grid,
    probe: np.ndarray,
    radius: np.ndarray,
    tol: float,
) -> int:
    """How many of ``probe`` (K, 2, px) lie within ``radius`` (K,) px (each at most ``tol``) of
    a ``plane`` point (``grid``: ``cell_grid(plane, tol)``)."""
    near = grid_nearest(plane, grid, probe, tol)
    return int(np.count_nonzero(near < radius))


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
    grid = cell_grid(plane, float(tol))
    H, H2 = np.ascontiguousarray(H, dtype=np.float64), np.ascontiguousarray(H2, dtype=np.float64)
    hits, radius = period_hits(plane, H, H2, grid, float(tol), float(rel))
    if hits < 0:  # H is singular
        return None
    # chance: the same radii around uniform points in the plane's bounding box
    probe = rng.uniform(grid[0], grid[1], (len(radius), 2))
    chance = count_near(plane, grid, probe, radius, float(tol))
    if hits < max(min_self_share * len(plane), 3.0 * chance):
        return None
    return on2
