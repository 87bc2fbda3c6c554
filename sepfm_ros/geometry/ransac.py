"""Generic RANSAC pieces: trial counts (the paper's F(k, r))."""

from __future__ import annotations

import math


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
    w = (1.0 - r) ** k
    if w >= 1.0:
        n = 1
    elif w <= 0.0:
        n = math.inf
    else:
        denom = math.log1p(-w)
        n = math.inf if denom == 0.0 else math.ceil(math.log1p(-confidence) / denom)
    if max_trials is not None:
        n = min(n, max_trials)
    if n == math.inf:
        raise ValueError("F(k, r) is infinite for r = 1; pass max_trials")
    return max(1, int(n))
