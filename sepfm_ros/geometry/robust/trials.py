"""Trial counts: the paper's F(k, r), the number of samples of k points RANSAC draws to find one
all-inlier sample with confidence p at outlier rate r."""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["ransac_trials", "trial_count", "trials_needed"]


@numba.njit(cache=True, nogil=True)
def trial_count(k: int, inlier_ratio: float, confidence: float) -> float:
    """The paper's F(k, r) at r = 1 - ``inlier_ratio``, uncapped (inf when no sample of k can be
    all inliers); the one implementation behind :func:`ransac_trials`, the RANSAC loop and the
    compiled stage 1.

    F(k, r) = ceil(log(1 - p) / log(1 - (1 - r)^k)), at least 1; p is ``confidence``.
    """
    w = inlier_ratio**k
    if w >= 1.0:
        return 1.0
    if w <= 0.0:
        return np.inf
    denom = np.log1p(-w)
    if denom == 0.0:
        return np.inf
    return max(1.0, np.ceil(np.log1p(-confidence) / denom))


@numba.njit(cache=True, nogil=True)
def trials_needed(k: int, count: int, n: int, confidence: float, cap: int) -> int:
    """F(k, r) for the inlier ratio ``count`` / ``n`` of the best model so far, capped at ``cap``
    (``cap`` before any inlier is known)."""
    w = min(1.0, count / n) if n > 0 else 0.0
    return int(min(trial_count(k, w, confidence), float(cap)))


def ransac_trials(k: int, r: float, confidence: float = 0.99, max_trials: int | None = None) -> int:
    """The paper's F(k, r): RANSAC trials needed to draw one all-inlier sample of size k.

    F(k, r) = ceil(log(1 - p) / log(1 - (1 - r)^k)), with r the outlier rate and p the confidence.

    Args:
        k: sample size (number of correspondences drawn per trial), >= 1.
        r: outlier rate in [0, 1].
        confidence: probability p in (0, 1) of drawing at least one all-inlier sample.
        max_trials: optional cap on the result.
    Returns:
        The number of trials (>= 1), or ``max_trials`` when r = 1 or the count exceeds it.
    """
    if k < 1:
        raise ValueError(f"sample size k must be >= 1, got {k}")
    if not 0.0 <= r <= 1.0:
        raise ValueError(f"outlier rate r must be in [0, 1], got {r}")
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must be in (0, 1), got {confidence}")
    n = trial_count(int(k), 1.0 - r, float(confidence))
    if max_trials is not None:
        n = min(n, max_trials)
    if n == math.inf:
        raise ValueError("F(k, r) is infinite for r = 1; pass max_trials")
    return max(1, int(n))
