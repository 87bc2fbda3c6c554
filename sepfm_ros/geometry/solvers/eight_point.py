"""Eight-point algorithm (linear least squares, rank-2 enforced), batched."""

from __future__ import annotations

import numpy as np

from sepfm_ros.geometry.epipolar import enforce_rank2
from sepfm_ros.geometry.solvers.design import epipolar_rows


def eight_point(x1: np.ndarray, x2: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """F from K >= 8 correspondences per sample, in the coordinates given (normalise first).

    Args:
        x1, x2: (M, K, 2) or (K, 2) correspondences, K >= 8.
        weights: optional (M, K) or (K,) non-negative row weights (for IRLS refinement).
    Returns:
        (M, 3, 3) or (3, 3) rank-2 F with x2^T F x1 = 0, unit Frobenius norm.
    """
    single = x1.ndim == 2
    if single:
        x1, x2 = x1[None], x2[None]
        if weights is not None:
            weights = weights[None]
    if x1.shape[-2] < 8:
        raise ValueError(f"eight_point needs >= 8 correspondences, got {x1.shape[-2]}")
    A = epipolar_rows(x1, x2)
    if weights is not None:
        A = A * weights[..., None]
    # Null vector of A through the 9x9 normal matrix: cheaper than SVD of (K, 9) for large K.
    AtA = np.swapaxes(A, -1, -2) @ A
    _, vecs = np.linalg.eigh(AtA)
    F = vecs[..., :, 0].reshape(-1, 3, 3)
    F = enforce_rank2(F)
    F /= np.linalg.norm(F.reshape(-1, 9), axis=1)[:, None, None]
    return F[0] if single else F
