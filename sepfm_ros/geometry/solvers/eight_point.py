"""Eight-point algorithm (linear least squares, rank-2 enforced), batched and compiled."""

from __future__ import annotations

import numba
import numpy as np

from sepfm_ros.geometry.epipolar import rank2_unit_kernel
from sepfm_ros.geometry.solvers.design import add_outer, design_row, null_basis, symmetrize


@numba.njit(cache=True, nogil=True)
def eight_point_kernel(x1: np.ndarray, x2: np.ndarray, w: np.ndarray) -> np.ndarray:
    """(M, K, 2) normalised samples, (M, K) row weights -> (M, 3, 3) rank-2 unit-norm F.

    K = 8: the exact null vector by elimination; K > 8 (or a rank-deficient sample): the
    least-squares one from the 9x9 normal matrix (cheaper than an SVD of (K, 9) rows).
    """
    M, K = x1.shape[0], x1.shape[1]
    out = np.empty((M, 3, 3))
    r = np.empty(9)
    A = np.empty((K, 9))
    basis = np.empty((1, 9))
    F = np.empty((3, 3))
    for m in range(M):
        exact = False
        if K == 8:  # minimal sample: the null vector by elimination (row weights do not matter)
            for k in range(K):
                design_row(x1[m, k, 0], x1[m, k, 1], x2[m, k, 0], x2[m, k, 1], A[k])
            exact = null_basis(A, basis)
            for i in range(9):
                F[i // 3, i % 3] = basis[0, i]
        if not exact:
            G = np.zeros((9, 9))
            for k in range(K):
                design_row(x1[m, k, 0], x1[m, k, 1], x2[m, k, 0], x2[m, k, 1], r)
                add_outer(G, r, w[m, k] * w[m, k])
            symmetrize(G)
            if not np.isfinite(G).all():
                for i in range(9):
                    out[m, i // 3, i % 3] = np.nan
                continue
            _, vecs = np.linalg.eigh(G)
            for i in range(9):
                F[i // 3, i % 3] = vecs[i, 0]
        G3 = rank2_unit_kernel(F)
        for i in range(9):
            out[m, i // 3, i % 3] = G3[i // 3, i % 3]
    return out


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
    w = np.ones(x1.shape[:2]) if weights is None else np.broadcast_to(weights, x1.shape[:2])
    F = eight_point_kernel(
        np.ascontiguousarray(x1, dtype=np.float64),
        np.ascontiguousarray(x2, dtype=np.float64),
        np.ascontiguousarray(w, dtype=np.float64),
    )
    return F[0] if single else F
