"""A DEGENSAC-style check of a final F against a dominant plane (plane-and-parallax).

When most inliers of a scene lie on one plane, RANSAC often returns an F fitted to a sample that
was (nearly) all on the plane: such an F explains the whole plane (a planar scene admits a
3-parameter family of F) but not the off-plane points, and adaptive stopping ends the search
before an all-inlier sample with enough off-plane points is drawn. DEGENSAC (Chum, Werner,
Matas, CVPR 2005) repairs this by estimating the plane's homography H and then F = [e']_x H from
H and just two off-plane correspondences (plane and parallax), which needs few samples.

:func:`plane_and_parallax` does this after the estimator: if a homography explains at least
``plane_share`` of F's inliers and F's support off the plane is not clearly above chance (see
below; checked first, as it is cheap), F = [e']_x H is hypothesised from random pairs of matches
off the plane, each candidate (and a least-squares refit of the best) is scored with the same
truncated quadratic (MSAC) cost as the estimator, and the best of the original F and the
candidates is returned. The original F is kept unless a candidate has a strictly lower cost.

A lower cost is not always enough: with many outliers, an F fitted to the plane can collect more
chance agreements from outliers than the true F gains from a few off-plane points, and then the
wrong F is the better one by any inlier-counting cost. So the check also asks whether F's support
*off the plane* is more than chance: the off-plane matches are re-paired at random (pts2
shuffled) and counted against F the same way; the off-plane inliers must exceed that chance
count by ``min_excess`` and by three standard deviations, otherwise F is flagged as determined by
the plane alone (``reason``). Only matches with clear parallax count as off the plane (transfer
error over ``parallax_factor`` times the homography tolerance): matches just off the plane
(mislocalised or near-miss matches of a planar scene, or a purely rotating camera) agree with
some member of the plane's family of F far more often than chance, and the estimator picks
exactly that member.

The plane-and-parallax candidates are tried unless F's off-plane support is well beyond the
flagging bar (``accept_factor`` times it): the F that reaches the check was fitted to the
matches (local optimisation moves its epipole to gather off-plane matches, two degrees of
freedom), so its off-plane count carries a selection the shuffled count does not see. An F just
over the bar may be a plane's F fitted to a few parallax matches, and a candidate through the
plane and two of them shows whether the data hold a better one.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numba
import numpy as np

from sepfm_ros.geometry.epipolar import (
    homogeneous,
    homogeneous_columns,
    msac_kernel,
    normalize_fundamental,
    paired_hits_kernel,
    symmetric_epipolar_distance_h,
)
from sepfm_ros.geometry.epipolar import symmetric_epipolar_distance as _sed
from sepfm_ros.geometry.fundamental.correspondences import Correspondences
from sepfm_ros.geometry.fundamental.refine import fit_least_squares, iterative_refit
from sepfm_ros.geometry.robust.trials import ransac_trials, trials_needed

#: A match lies on the plane's homography when its transfer error is below this x the threshold.
PLANE_TOLERANCE = 2.0


@dataclass
class PlaneCheck:
    """Result of :func:`plane_and_parallax`.

    Attributes:
        F: (3, 3) the model to use (unit norm): the input F or a better one.
        replaced: True when a plane-and-parallax model beat the input F.
        planar: True when a homography explained at least ``plane_share`` of F's inliers.
        plane_inliers: inliers of the returned F that lie on the homography.
        off_plane_inliers: inliers of the returned F off the homography.
        candidates: plane-and-parallax models scored.
        off_plane_chance: off-plane inliers expected by chance (shuffled pairs), mean.
        reason: why F is not supported off the plane ("degenerate: ..."), or None.
        H: the homography of the plane that was tested, or None.
        accepted: F was kept without trying candidates: its support off the plane is at least
            ``accept_factor`` times the flagging bar above chance.
        transfer: (N,) px, ``transfer_error(H, ...)`` of the matches the check was given.
    """

    F: np.ndarray
    replaced: bool = False
    planar: bool = False
    plane_inliers: int = 0
    off_plane_inliers: int = 0
    candidates: int = 0
    off_plane_chance: float = 0.0
    reason: str | None = None
    H: np.ndarray | None = None  #: (3, 3) the plane's homography (image 1 -> 2) when found
    accepted: bool = False
    #: (N,) px, the transfer error of H on the matches the check was given (None without H)
    transfer: np.ndarray | None = None


def robust_homography(
    pts1: np.ndarray,
    pts2: np.ndarray,
    tol: float,
    min_share: float,
    seed: int,
    max_trials: int,
) -> np.ndarray | None:
    """A homography that holds ``min_share`` of the (K >= 4, 2) matches pts1 -> pts2 within
    ``tol`` px: OpenCV's RHO, its RNG seeded with ``seed``, drawing F(4, 1 - min_share) samples
    at confidence 0.995 (at most ``max_trials``). Returns (3, 3) H, image 1 -> image 2, or None
    when OpenCV finds none."""
    cv2.setRNGSeed(int(seed))
    iters = ransac_trials(4, 1.0 - min_share, 0.995, max_trials=max_trials)
    H, _ = cv2.findHomography(pts1, pts2, cv2.RHO, tol, maxIters=iters, confidence=0.995)
    return H


def transfer_error(H: np.ndarray, pts1: np.ndarray, pts2: np.ndarray) -> np.ndarray:
    """(N,) ||H x1 - x2|| in px (inf where H maps to infinity)."""
    return _transfer_error(
        np.ascontiguousarray(H, dtype=np.float64),
        np.ascontiguousarray(pts1, dtype=np.float64),
        np.ascontiguousarray(pts2, dtype=np.float64),
    )


@numba.njit(cache=True, nogil=True)
def _transfer_error(H: np.ndarray, pts1: np.ndarray, pts2: np.ndarray) -> np.ndarray:
    out = np.empty(len(pts1))
    for i in range(len(pts1)):
        x, y = pts1[i, 0], pts1[i, 1]
        w = H[2, 0] * x + H[2, 1] * y + H[2, 2]
        if w == 0.0:
            out[i] = np.inf
            continue
        du = (H[0, 0] * x + H[0, 1] * y + H[0, 2]) / w - pts2[i, 0]
        dv = (H[1, 0] * x + H[1, 1] * y + H[1, 2]) / w - pts2[i, 1]
        e = np.sqrt(du * du + dv * dv)
        out[i] = e if np.isfinite(e) else np.inf
    return out


def parallax_models(
    H: np.ndarray, pts1: np.ndarray, pts2: np.ndarray, pairs: np.ndarray
) -> np.ndarray:
    """F = [e']_x H for (M, 2) index pairs of off-plane matches -> (M, 3, 3), unit norm.

    The epipole e' in image 2 is the intersection of the lines through H x_i and x'_i (the
    parallax lines) of the two matches.
    """
    x1 = homogeneous(pts1)
    x2 = homogeneous(pts2)
    hx = x1 @ H.T
    lines = np.cross(hx, x2)  # (N, 3) parallax line of every match
    e = np.cross(lines[pairs[:, 0]], lines[pairs[:, 1]])  # (M, 3)
    ex = np.zeros((len(e), 3, 3))
    ex[:, 0, 1], ex[:, 0, 2] = -e[:, 2], e[:, 1]
    ex[:, 1, 0], ex[:, 1, 2] = e[:, 2], -e[:, 0]
    ex[:, 2, 0], ex[:, 2, 1] = -e[:, 1], e[:, 0]
    return normalize_fundamental(ex @ H)


def random_pairs(rng: np.random.Generator, items: np.ndarray, k: int) -> np.ndarray:
    """(k, 2) ordered pairs of two different entries of ``items`` (M >= 2,), each pair drawn
    uniformly and independently (the second entry uniform among the other M - 1)."""
    i = rng.integers(0, len(items), k)
    j = rng.integers(0, len(items) - 1, k)
    return np.stack([items[i], items[j + (j >= i)]], axis=1)


def plane_and_parallax(
    F: np.ndarray,
    pts1: np.ndarray,
    pts2: np.ndarray,
    threshold: float,
    rng: np.random.Generator,
    plane_share: float = 0.5,
    max_candidates: int = 300,
    min_excess: int = 8,
    shuffles: int = 8,
    parallax_factor: float = 2.0,
    adaptive: bool = True,
    confidence: float = 0.99,
    batch: int = 16,
    plane_points: int = 150,
    accept_factor: float = 2.0,
    data: Correspondences | None = None,
) -> PlaneCheck:
    """Check a final F against a dominant plane; return it or a better plane-and-parallax F.

    Args:
        F: (3, 3) the estimator's F (x2^T F x1 = 0).
        pts1, pts2: (N, 2) all matches, px.
        threshold: inlier threshold, px of symmetric epipolar distance (the estimator's).
        rng: random generator (seeded by the caller) for the off-plane pairs and the H fit.
        plane_share: a homography must explain this share of F's inliers to trigger the check.
        max_candidates: off-plane pairs tried (all pairs when there are fewer).
        min_excess: off-plane inliers needed beyond the chance count (see the module docstring).
        accept_factor: F is kept without trying candidates when its off-plane excess over
            chance is at least this times the bar of ``min_excess`` (see the module docstring).
        shuffles: random re-pairings averaged for the chance count.
        parallax_factor: a match counts as off the plane (evidence for F) when its transfer
            error exceeds this times the homography tolerance (2 x ``threshold``).
        adaptive: try off-plane pairs in batches of ``batch`` and stop once F(2, w) were tried
            at ``confidence``, w the best candidate's share of inliers among the off-plane
            matches (otherwise all ``max_candidates``).
        plane_points: the homography is searched among at most this many of F's inliers,
            drawn at random (its share of all of them is then counted); the search's time
            grows with the points while the share it has to find does not.
        data: the matches pts1, pts2 prepared (``Correspondences.from_pixels``), when the
            caller has them (made here otherwise, when candidates are tried).
    Returns:
        A :class:`PlaneCheck`.
    """
    F = normalize_fundamental(F)
    tol = PLANE_TOLERANCE * threshold
    X1, X2 = (data.X1, data.X2) if data is not None else (None, None)
    inl = _distances(F, pts1, pts2, X1, X2) < threshold
    out = PlaneCheck(F)
    if np.count_nonzero(inl) < 8:
        return out
    # a robust H on F's inliers (the question is whether one plane holds plane_share of them;
    # matches F rejected would only slow the search down); F(4, 1 - plane_share) samples find
    # such a plane with confidence 0.995 (83 at 0.5) where a non-planar scene would run to 500
    # (matches along one line, whose 4-point samples are degenerate for H, are flagged by the
    # estimator's line-band check instead)
    seed = int(rng.integers(0, 2**31 - 1))
    fit = np.flatnonzero(inl)
    if len(fit) > plane_points:  # a random subset holds the plane's share as well
        fit = np.sort(rng.choice(fit, plane_points, replace=False))
    H = robust_homography(pts1[fit], pts2[fit], tol, plane_share, seed, max_trials=500)
    if H is None:
        return out
    out.H = H
    err_h = out.transfer = transfer_error(H, pts1, pts2)
    on = err_h < tol
    far = err_h > parallax_factor * tol  # clear parallax: evidence about F beyond the plane
    out.plane_inliers = int(np.count_nonzero(on & inl))
    out.off_plane_inliers = int(np.count_nonzero(far & inl))
    if out.plane_inliers < plane_share * np.count_nonzero(inl):
        return out
    out.planar = True
    off = np.flatnonzero(~on)
    if len(off) < 2:
        out.reason = f"degenerate: dominant plane (all {len(pts1)} matches on one homography)"
        return out
    # cheap test first: an F whose support off the plane is far above chance is determined by
    # the data; only an F without it is challenged by plane-and-parallax candidates
    out.off_plane_chance = chance_inliers(F, pts1[far], pts2[far], threshold, rng, shuffles)
    if out.off_plane_inliers - out.off_plane_chance >= accept_factor * max(
        min_excess, 3.0 * np.sqrt(out.off_plane_chance + 1.0)
    ):
        out.accepted = True
        return out
    n_pairs = len(off) * (len(off) - 1) // 2
    if n_pairs <= max_candidates:
        i, j = np.triu_indices(len(off), 1)
        pairs = np.stack([off[i], off[j]], axis=1)
        if adaptive:
            pairs = pairs[rng.permutation(len(pairs))]
    else:
        pairs = random_pairs(rng, off, max_candidates)
    if data is None:
        data = Correspondences.from_pixels(pts1, pts2)
    X1o, X2o = np.ascontiguousarray(data.X1[:, off]), np.ascontiguousarray(data.X2[:, off])
    best, best_cost, tried, start = None, np.inf, 0, 0
    while start < len(pairs):
        # adaptive: stop once F(2, w) pairs were tried, w the best candidate's off-plane inlier
        # share (a candidate is right when both its off-plane matches are inliers)
        stop = len(pairs) if not adaptive else start + batch
        models = parallax_models(H, pts1, pts2, pairs[start:stop])
        start = min(stop, len(pairs))
        models = models[np.isfinite(models).all(axis=(1, 2))]
        tried += len(models)
        if len(models):
            costs, _ = msac_kernel(np.ascontiguousarray(models), data.X1, data.X2, threshold)
            k = int(np.argmin(costs))
            if costs[k] < best_cost:
                best, best_cost = models[k], float(costs[k])
        if adaptive and best is not None:
            _, off_count = msac_kernel(np.ascontiguousarray(best[None]), X1o, X2o, threshold)
            if start >= trials_needed(2, int(off_count[0]), len(off), confidence, len(pairs)):
                break
    out.candidates = tried
    if best is None:
        return out
    # polish the best candidate like the estimator polishes its final model
    choices = [best, *iterative_refit(best, data, threshold)]
    best_inl = _distances(best, pts1, pts2, data.X1, data.X2) < threshold
    if np.count_nonzero(best_inl) >= 8:
        choices.append(fit_least_squares(pts1[best_inl], pts2[best_inl], irls_iterations=5))
    options = np.ascontiguousarray(np.stack([*choices, F]))
    option_costs, _ = msac_kernel(options, data.X1, data.X2, threshold)
    k = int(np.argmin(option_costs[:-1]))
    # the last row is the input F; a candidate that fits the plane's matches closer but keeps
    # fewer of the clear-parallax ones than F does trades F's evidence off the plane for noise
    # on it (with a handful of off-plane points its lower cost says nothing), so F stays
    new_inl = None
    if option_costs[k] < option_costs[-1]:
        new_inl = _distances(options[k], pts1, pts2, data.X1, data.X2) < threshold
    if new_inl is not None and np.count_nonzero(far & new_inl) >= out.off_plane_inliers:
        out.F = normalize_fundamental(options[k])
        out.replaced = True
        out.plane_inliers = int(np.count_nonzero(on & new_inl))
        out.off_plane_inliers = int(np.count_nonzero(far & new_inl))
    out.off_plane_chance = chance_inliers(out.F, pts1[far], pts2[far], threshold, rng, shuffles)
    excess = out.off_plane_inliers - out.off_plane_chance
    if excess < max(min_excess, 3.0 * np.sqrt(out.off_plane_chance + 1.0)):
        out.reason = (
            f"degenerate: dominant plane ({out.plane_inliers} inliers on one homography, "
            f"{out.off_plane_inliers} off it where {out.off_plane_chance:.1f} agree by chance)"
        )
    return out


def _distances(
    F: np.ndarray,
    pts1: np.ndarray,
    pts2: np.ndarray,
    X1: np.ndarray | None,
    X2: np.ndarray | None,
) -> np.ndarray:
    """(N,) symmetric epipolar distances (px) of the matches to F (3, 3): on their homogeneous
    columns X1, X2 (3, N) when given (the same kernel, without building them again)."""
    if X1 is None or X2 is None:
        return _sed(F, pts1, pts2)
    return symmetric_epipolar_distance_h(np.asarray(F, dtype=np.float64)[None], X1, X2)[0]


def chance_inliers(
    F: np.ndarray,
    pts1: np.ndarray,
    pts2: np.ndarray,
    threshold: float,
    rng: np.random.Generator,
    shuffles: int = 8,
) -> float:
    """Mean number of (N, 2) matches within ``threshold`` of F after pts2 is shuffled at random."""
    n = len(pts1)
    if n < 2:
        return 0.0
    perms = rng.permuted(np.tile(np.arange(n), (shuffles, 1)), axis=1)  # (S, N)
    i1 = np.tile(np.arange(n), shuffles)  # pairing s N + i: match i's point 1, perms[s, i]'s 2
    X1, X2 = homogeneous_columns(pts1), homogeneous_columns(pts2)
    F = np.ascontiguousarray(F, dtype=np.float64)
    return paired_hits_kernel(F, X1, X2, i1, perms.ravel(), float(threshold)) / shuffles
