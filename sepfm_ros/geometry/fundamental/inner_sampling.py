"""Inner sampling of the final model: LO-RANSAC's inner RANSAC (Chum, Matas & Kittler 2003),
run once on the model a search ends with.

A search stops when F(k, r) samples make an all-inlier sample likely; local optimisation from
that sample reaches the best model of its basin, not necessarily the best basin. The separable
method stops after few samples (its saving), so it tries few basins. Inner sampling draws
``samples`` non-minimal samples of ``size`` matches from the inliers of the final model, fits
each by least squares (normalised eight-point), and runs the refits of local optimisation
(:meth:`FundamentalProblem.local_optimize`: iterative least squares on the inliers under a
shrinking threshold, without the Levenberg-Marquardt step) from the fit with the lowest MSAC
cost. A refit replaces the model only if it lowers the MSAC cost at the threshold without
raising the MSAC cost at the model's noise truncation (``nonlinear.noise_truncation``): on noisy
matches (ORB on video frames) a 1 px cost alone prefers a model that fits a tight subset of the
matches and misses the rest.

Only a model with under MAX_INLIER_RATIO of the matches as inliers is sampled: when most matches
are inliers, most of the search's samples were all-inlier and its local optimisation started
from many of them, so the inner samples found no better basin (measured on the node's KITTI
and templeRing pairs, the shared pairs and the line-rich scenes: equal F-scores, 6-9 % less
time where the ratio is high).
"""

from __future__ import annotations

import numba
import numpy as np

from sepfm_ros.geometry.epipolar import msac_cost, msac_kernel
from sepfm_ros.geometry.fundamental.nonlinear import noise_truncation
from sepfm_ros.geometry.fundamental.problem import FundamentalProblem
from sepfm_ros.geometry.fundamental.refine import normalized_model, refit_kernel
from sepfm_ros.geometry.robust.samplers import draw_samples

#: Matches per inner sample: twice the seven of a minimal sample.
INNER_SAMPLE_SIZE = 14
#: Inlier ratio (inliers / matches) of the final model from which it is not inner-sampled.
MAX_INLIER_RATIO = 0.7


def inner_sampling(
    F: np.ndarray,
    problem: FundamentalProblem,
    rng: np.random.Generator,
    samples: int,
    size: int = INNER_SAMPLE_SIZE,
) -> tuple[np.ndarray, int]:
    """Inner sampling from the final model F (3, 3) (see the module docstring).

    Args:
        F: the model the search ended with, px. problem: an MSAC-scored problem over all
            matches (its threshold and refits are used; its samples not).
        rng: the generator of the inner samples (the estimator passes a stream spawned from
            the estimate's, so the other steps draw the same with and without them).
        samples: inner samples to draw (0: F is returned unchanged).
        size: matches per inner sample (>= 8).
    Returns:
        (F' (3, 3), models scored): F' is F or the refit the rule above picks; F unchanged
        when F has fewer than 2 x ``size`` inliers or at least MAX_INLIER_RATIO of the
        matches are its inliers.
    """
    if samples <= 0:
        return F, 0
    data, threshold = problem.data, problem.threshold
    inliers = np.flatnonzero(data.distances(F) < threshold)
    if len(inliers) < 2 * size or len(inliers) >= MAX_INLIER_RATIO * len(data):
        return F, 0
    drawn = draw_samples(rng, inliers, size, samples)
    best = _best_inner_fit(
        np.ascontiguousarray(F, dtype=np.float64), data.x1, data.x2, data.X1, data.X2,
        data.T1, data.T2, drawn, float(threshold),
    )  # fmt: skip
    optimized = problem.local_optimize(best)
    candidates = np.ascontiguousarray(np.concatenate([F[None], optimized]))
    cost, _ = msac_kernel(candidates, data.X1, data.X2, threshold)
    wide, _ = msac_kernel(candidates, data.X1, data.X2, noise_truncation(F, data, threshold))
    cost[wide > wide[0]] = np.inf  # never worse at the noise truncation than F
    return candidates[int(np.argmin(cost))], samples + len(optimized)


@numba.njit(cache=True, nogil=True)
def _best_inner_fit(
    F: np.ndarray,
    x1: np.ndarray,
    x2: np.ndarray,
    X1: np.ndarray,
    X2: np.ndarray,
    T1: np.ndarray,
    T2: np.ndarray,
    drawn: np.ndarray,
    threshold: float,
) -> np.ndarray:
    """The least-squares fit (3, 3) of the sample (row of ``drawn`` (S, size), match indices)
    with the lowest MSAC cost at ``threshold`` over all matches (X1, X2: (>=2, N) px; x1, x2:
    (N, 2) normalised). Each fit starts its inverse iteration from F (the samples are F's
    inliers); a fit's scoring stops once its partial cost passes the best so far."""
    start = normalized_model(F, T1, T2)
    best = F.copy()
    best_cost = np.inf
    for s in range(drawn.shape[0]):
        G = refit_kernel(x1, x2, drawn[s], 0, T1, T2, start)
        c, _ = msac_cost(G, X1, X2, threshold, best_cost)
        if c < best_cost:
            best_cost = c
            best = G
    return best
