"""Least-squares refits on inliers and Sampson-error refinement (IRLS), rank 2 enforced.

Used by local optimisation inside RANSAC (LO-RANSAC) and for the final model. All fits work on
the design rows of :class:`Correspondences` (normalised coordinates, computed once), so a refit
costs one weighted 9x9 Gram matrix and one eigen-decomposition.
"""

from __future__ import annotations

import numpy as np

from sepfm_ros.geometry.correspondences import Correspondences
from sepfm_ros.geometry.epipolar import (
    denormalize,
    enforce_rank2,
    normalize_fundamental,
)

#: Inlier-threshold factors of :func:`iterative_refit`, loosest first (LO-RANSAC's iterative step).
REFIT_FACTORS = (3.0, 1.5, 1.0, 1.0)


def _solve_rows(rows: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Rank-2 F_n (3, 3) minimising ||diag(w) rows vec(F)|| for (K, 9) rows, K >= 8."""
    A = rows if weights is None else rows * weights[:, None]
    _, vecs = np.linalg.eigh(A.T @ A)
    return enforce_rank2(vecs[:, 0].reshape(3, 3))


def _sampson_weights(F_n: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
    """1 / ||grad(x2^T F x1)|| per correspondence (the Sampson denominator), scaled to max 1."""
    l2 = x1 @ F_n[:, :2].T + F_n[:, 2]  # (K, 3) = F x1
    l1 = x2 @ F_n[:2, :] + F_n[2, :]  # (K, 3) = F^T x2
    g = np.sqrt(l2[:, 0] ** 2 + l2[:, 1] ** 2 + l1[:, 0] ** 2 + l1[:, 1] ** 2)
    w = 1.0 / np.maximum(g, 1e-12 * max(float(g.max()), 1e-300))
    return w / w.max()


def refit(data: Correspondences, inliers: np.ndarray, irls_iterations: int = 0) -> np.ndarray:
    """Normalised eight-point least squares on the inliers, then Sampson IRLS iterations.

    Args:
        data: the matches. inliers: (N,) bool with at least 8 True.
        irls_iterations: reweighted solves that reduce the Sampson error (0: plain least squares).
    Returns:
        (3, 3) rank-2 F in pixels, unit Frobenius norm.
    """
    rows = data.rows[inliers]
    F_n = _solve_rows(rows)
    x1, x2 = data.x1[inliers], data.x2[inliers]
    for _ in range(irls_iterations):
        F_n = _solve_rows(rows, _sampson_weights(F_n, x1, x2))
    return normalize_fundamental(denormalize(F_n, data.T1, data.T2))


def fit_least_squares(pts1: np.ndarray, pts2: np.ndarray, irls_iterations: int = 0) -> np.ndarray:
    """F (3, 3) from K >= 8 pixel correspondences (K, 2): normalised eight-point (+ IRLS)."""
    data = Correspondences.from_pixels(pts1, pts2)
    return refit(data, np.ones(len(data), dtype=bool), irls_iterations)


def iterative_refit(
    F: np.ndarray,
    data: Correspondences,
    threshold: float,
    factors: tuple[float, ...] = REFIT_FACTORS,
    irls_iterations: int = 2,
) -> list[np.ndarray]:
    """Refit F on its inliers under a shrinking threshold (LO-RANSAC's iterative least squares).

    Each step takes the inliers of the current model at ``factor * threshold`` px (symmetric
    epipolar distance) and refits them (:func:`refit`); a step's model becomes current only if
    its truncated-quadratic (MSAC) cost at ``threshold`` is lower. From a rough model (e.g. one
    whose minimal sample was badly conditioned) this reaches the best model of its basin.

    Args:
        F: (3, 3) start model in pixels. data: all matches.
    Returns:
        Every model fitted on the way (each was scored against all matches; the caller picks
        the best by its own scoring); empty when no step had 8 inliers.
    """
    t2 = threshold * threshold
    d = data.distances(F)
    best_cost = float(np.minimum(d * d, t2).sum())
    fitted: list[np.ndarray] = []
    previous = None
    for factor in factors:
        inl = d < factor * threshold
        if np.count_nonzero(inl) < 8:
            continue
        if previous is not None and np.array_equal(inl, previous):
            if factor == factors[-1]:
                break
            continue
        previous = inl
        G = refit(data, inl, irls_iterations)
        dG = data.distances(G)
        c = float(np.minimum(dG * dG, t2).sum())
        fitted.append(G)
        if c < best_cost:  # continue from the better model
            best_cost, d = c, dG
    return fitted
