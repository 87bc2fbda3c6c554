"""A contrario significance of a consensus: could random matches have given it?

Any F fitted to matches that carry no geometry at all (two unrelated images, random pairings)
still gathers some matches within the threshold: RANSAC keeps the best of thousands of models,
and on 1,000 random matches in a 640 x 480 image the best one has about 15 inliers. Counting
inliers alone cannot tell that from a real pair with 15 true matches among 55.

Moisan and Stival's number of false alarms (ORSA, "A probabilistic criterion to detect rigid
point matches between two images and estimate the fundamental matrix", IJCV 2004) measures it: of
n matches, k lie within the threshold of F, each random match does with probability alpha, and

    NFA = M (n - s) C(n, k) C(k, s) alpha^(k - s)

bounds the expected number of models, over every s-point sample (s = 7, M = 3 models per sample)
and every set of k matches, that random matches would explain this well. NFA < 1 (log10 < 0) is
a consensus random matches do not give.

alpha is measured on the matches themselves (:func:`chance_rate`): the share of re-paired
matches (each image-1 point with another match's image-2 point) within the threshold of F. So
it follows where the points lie and how long F's epipolar lines run across them, not an
image-area bound.
"""

from __future__ import annotations

import math

import numpy as np

from sepfm_ros.geometry.epipolar import paired_hits_kernel
from sepfm_ros.geometry.fundamental.correspondences import Correspondences

#: Sample size s and models per sample M of :func:`log10_nfa` (the seven-point solver: F has 7
#: degrees of freedom, and a sample gives up to 3 models).
SAMPLE_SIZE = 7
MODELS_PER_SAMPLE = 3
#: Re-paired matches :func:`chance_rate` measures, so that a rate near 1e-3 is counted about ten
#: times.
CHANCE_PAIRINGS = 10000
#: Re-paired matches of the first, cheap draw of :func:`consensus_log10_nfa`.
QUICK_PAIRINGS = 1000
#: log10 NFA below which a consensus counts as significant (ORSA's epsilon = 1: fewer than one
#: model this good expected from random matches).
MAX_LOG10_NFA = 0.0


def chance_rate(
    F: np.ndarray,
    X1: np.ndarray,
    X2: np.ndarray,
    threshold: float,
    rng: np.random.Generator,
    pairings: int = CHANCE_PAIRINGS,
) -> tuple[float, float]:
    """alpha: the share of random re-pairings of the matches within ``threshold`` of F, and a
    bound above it.

    Each of the ``pairings`` pairs match i's point in image 1 (i running over the matches in
    turn) with the image-2 point of another match j != i drawn by ``rng`` (a match's own
    pairing is no chance agreement).

    Args:
        F: (3, 3) model, x2^T F x1 = 0, px. X1, X2: (>=2, N) pixel points of the N >= 2 matches
            (homogeneous columns). threshold: px of symmetric epipolar distance.
    Returns:
        (hits + 1) / (P + 1) for the P pairings (never 0, so a rate too small to count stays
        finite), and (hits + 2 + 3 sqrt(hits + 1)) / P, which the rate exceeds by chance
        rarely (about three standard deviations of a Poisson count).
    """
    n = X1.shape[1]
    i1 = np.arange(pairings) % n
    i2 = (i1 + rng.integers(1, n, pairings)) % n
    F = np.ascontiguousarray(F, dtype=np.float64)
    hits = int(paired_hits_kernel(F, X1, X2, i1, i2, float(threshold)))
    upper = (hits + 2.0 + 3.0 * math.sqrt(hits + 1.0)) / pairings
    return (hits + 1.0) / (pairings + 1.0), min(1.0, upper)


def _log10_binomial(n: int, k: int) -> float:
    return (math.lgamma(n + 1) - math.lgamma(k + 1) - math.lgamma(n - k + 1)) / math.log(10.0)


def log10_nfa(
    n: int,
    k: int,
    alpha: float,
    sample_size: int = SAMPLE_SIZE,
    models_per_sample: int = MODELS_PER_SAMPLE,
) -> float:
    """log10 of M (n - s) C(n, k) C(k, s) alpha^(k - s) (see module), for k > s inliers of n
    matches, each random match within the threshold with probability alpha in (0, 1]; +inf
    when k <= s (a sample's own points are no evidence)."""
    s = sample_size
    if k <= s or n <= s:
        return math.inf
    return (
        math.log10(models_per_sample)
        + math.log10(n - s)
        + _log10_binomial(n, k)
        + _log10_binomial(k, s)
        + (k - s) * math.log10(alpha)
    )


def consensus_log10_nfa(
    F: np.ndarray,
    data: Correspondences,
    inliers: np.ndarray,
    threshold: float,
    rng: np.random.Generator,
) -> float:
    """log10 NFA of F's inliers (N,) bool among the matches ``data`` (see module); below
    ``MAX_LOG10_NFA`` the consensus is significant.

    A first draw of ``QUICK_PAIRINGS`` settles the clear cases (the NFA at the rate's upper
    bound already significant: hundreds of inliers); the others get ``CHANCE_PAIRINGS``.
    """
    k, n = int(np.count_nonzero(inliers)), len(data)
    if k <= SAMPLE_SIZE:
        return math.inf
    alpha, upper = chance_rate(F, data.X1, data.X2, threshold, rng, QUICK_PAIRINGS)
    if log10_nfa(n, k, upper) < MAX_LOG10_NFA:
        return log10_nfa(n, k, alpha)
    alpha, _ = chance_rate(F, data.X1, data.X2, threshold, rng)
    return log10_nfa(n, k, alpha)
