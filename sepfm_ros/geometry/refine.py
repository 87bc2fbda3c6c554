"""Final model: least-squares refit on inliers and Sampson-error refinement (IRLS), rank 2."""

from __future__ import annotations

import numpy as np

from sepfm_ros.geometry.epipolar import (
    apply_transform,
    denormalize,
    normalization_transform,
    normalize_fundamental,
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
