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
"""

from __future__ import annotations

import numpy as np

from sepfm_ros.geometry.epipolar import msac_kernel
from sepfm_ros.geometry.fundamental_problem import FundamentalProblem
from sepfm_ros.geometry.nonlinear import noise_truncation
from sepfm_ros.geometry.refine import refit

#: Matches per inner sample: twice the seven of a minimal sample.
INNER_SAMPLE_SIZE = 14


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
        when F has fewer than 2 x ``size`` inliers.
    """
    if samples <= 0:
        return F, 0
    data, threshold = problem.data, problem.threshold
    inliers = np.flatnonzero(data.distances(F) < threshold)
    if len(inliers) < 2 * size:
        return F, 0
    fits = np.empty((samples, 3, 3))
    for s in range(samples):
        mask = np.zeros(len(data), dtype=bool)
        mask[rng.choice(inliers, size, replace=False)] = True
        fits[s] = refit(data, mask)
    cost, _ = msac_kernel(fits, data.X1, data.X2, threshold)
    optimized = problem.local_optimize(fits[int(np.argmin(cost))])
    candidates = np.ascontiguousarray(np.concatenate([F[None], optimized]))
    cost, _ = msac_kernel(candidates, data.X1, data.X2, threshold)
    wide, _ = msac_kernel(candidates, data.X1, data.X2, noise_truncation(F, data, threshold))
    cost[wide > wide[0]] = np.inf  # never worse at the noise truncation than F
    return candidates[int(np.argmin(cost))], samples + len(optimized)
