"""Final model: least-squares refit on inliers and Sampson-error refinement (IRLS), rank 2."""

from __future__ import annotations

import numpy as np

from sepfm_ros.geometry.epipolar import (
    apply_transform,
    denormalize,
    normalization_transform,
    normalize_fundamental,
    symmetric_epipolar_distance,
)
from sepfm_ros.geometry.solvers.eight_point import eight_point


def fit_least_squares(pts1: np.ndarray, pts2: np.ndarray) -> np.ndarray:
    """Normalised eight-point least squares on K >= 8 correspondences (N, 2) -> F (3, 3)."""
    T1 = normalization_transform(pts1)
    T2 = normalization_transform(pts2)
    F_n = eight_point(apply_transform(T1, pts1), apply_transform(T2, pts2))
    return normalize_fundamental(denormalize(F_n, T1, T2))


def refine_sampson(
    F: np.ndarray, pts1: np.ndarray, pts2: np.ndarray, iterations: int = 5
) -> np.ndarray:
    """Reduce the Sampson error of F on K >= 8 inlier correspondences by reweighted eight-point.

    Each iteration solves the eight-point system with rows weighted by 1 / ||grad(x2^T F x1)||
    of the previous F (the Sampson denominator), which converges to the Sampson-error optimum
    (rank 2 enforced each step).

    Args:
        F: (3, 3) starting model (pixels). pts1, pts2: (K, 2) inliers in pixels.
    Returns:
        (3, 3) refined F, unit Frobenius norm.
    """
    T1 = normalization_transform(pts1)
    T2 = normalization_transform(pts2)
    x1 = apply_transform(T1, pts1)
    x2 = apply_transform(T2, pts2)
    # F in normalised coordinates: F_n = T2^-T F T1^-1
    F_n = np.linalg.inv(T2).T @ F @ np.linalg.inv(T1)
    h1 = np.concatenate([x1, np.ones((len(x1), 1))], axis=1)
    h2 = np.concatenate([x2, np.ones((len(x2), 1))], axis=1)
    for _ in range(iterations):
        l2 = h1 @ F_n.T
        l1 = h2 @ F_n
        g = np.sqrt(l2[:, 0] ** 2 + l2[:, 1] ** 2 + l1[:, 0] ** 2 + l1[:, 1] ** 2)
        w = 1.0 / np.maximum(g, 1e-12 * max(g.max(), 1e-300))
        F_n = eight_point(x1, x2, weights=w / w.max())
    return normalize_fundamental(denormalize(F_n, T1, T2))


#: Inlier-threshold factors of :func:`iterative_refit`, loosest first (LO-RANSAC's iterative step).
REFIT_FACTORS = (3.0, 2.0, 1.5, 1.0, 1.0, 1.0)


def iterative_refit(
    F: np.ndarray,
    pts1: np.ndarray,
    pts2: np.ndarray,
    threshold: float,
    factors: tuple[float, ...] = REFIT_FACTORS,
    irls_iterations: int = 5,
) -> list[np.ndarray]:
    """Refit F on its inliers under a shrinking threshold (LO-RANSAC's iterative least squares).

    Each step takes the inliers of the current model at ``factor * threshold`` px (symmetric
    epipolar distance), fits the normalised eight-point least squares on them and refines its
    Sampson error; a step's model becomes current only if its truncated-quadratic (MSAC) cost
    at ``threshold`` is lower. Starting from a rough model (e.g. one whose minimal sample was
    badly conditioned) this reaches the basin of the best model nearby.

    Args:
        F: (3, 3) start model. pts1, pts2: (N, 2) all matches in px.
    Returns:
        Every model fitted on the way (each was scored against all matches; the caller picks
        the best by its own scoring); empty when no step had 8 inliers.
    """
    t2 = threshold * threshold

    def cost(G: np.ndarray) -> tuple[float, np.ndarray]:
        d = symmetric_epipolar_distance(G, pts1, pts2)
        return float(np.minimum(d * d, t2).sum()), d

    best_cost, d = cost(F)
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
        G = fit_least_squares(pts1[inl], pts2[inl])
        if irls_iterations:
            G = refine_sampson(G, pts1[inl], pts2[inl], iterations=irls_iterations)
        c, dG = cost(G)
        fitted.append(G)
        if c < best_cost:  # continue from the better model
            best_cost, d = c, dG
    return fitted
