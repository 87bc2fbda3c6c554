"""Seven-point algorithm, batched and compiled: each real root of det(F) = 0 is one model."""

from __future__ import annotations

import numba
import numpy as np

from sepfm_ros.geometry.solvers.design import design_row, null_basis

# det(F2 + s (F1 - F2)) is a cubic in s; sample it at these s and solve for the coefficients.
_S = np.array([0.0, 1.0, -1.0, 2.0])
_VANDER_INV = np.linalg.inv(np.vander(_S, 4))  # rows: s^3, s^2, s, 1


@numba.njit(cache=True, nogil=True)
def _det_pencil(f2: np.ndarray, d: np.ndarray, s: float) -> float:
    """det(F2 + s D) of row-major (9,) F2 and D."""
    a = np.empty(9)
    for i in range(9):
        a[i] = f2[i] + s * d[i]
    return (
        a[0] * (a[4] * a[8] - a[5] * a[7])
        - a[1] * (a[3] * a[8] - a[5] * a[6])
        + a[2] * (a[3] * a[7] - a[4] * a[6])
    )


@numba.njit(cache=True, nogil=True)
def _seven_point_one(A: np.ndarray, vander_inv: np.ndarray, out: np.ndarray) -> int:
    """Real-root models of one sample's (K, 9) design rows into out (3, 9); returns how many.

    Models are row-major (9,) at unit norm.
    """
    f2 = np.empty(9)
    d = np.empty(9)
    basis = np.empty((2, 9))
    if A.shape[0] == 7 and null_basis(A, basis):  # minimal sample: exact null space
        for i in range(9):
            f2[i] = basis[0, i]
            d[i] = basis[1, i] - basis[0, i]
    else:  # K > 7 (or rank-deficient): the least-squares two-dimensional null space
        _, _, Vt = np.linalg.svd(A)  # full 9x9 Vt: its last two rows
        for i in range(9):
            f2[i] = Vt[7, i]
            d[i] = Vt[8, i] - Vt[7, i]
    dets = np.empty(4)
    for j in range(4):
        dets[j] = _det_pencil(f2, d, _S[j])
    coeffs = np.zeros(4)  # c3, c2, c1, c0
    scale = 0.0
    for i in range(4):
        for j in range(4):
            coeffs[i] += vander_inv[i, j] * dets[j]
        scale = max(scale, abs(coeffs[i]))
    if scale == 0:
        scale = 1.0
    c3 = coeffs[0]
    if abs(c3) < 1e-12 * scale:  # a root at infinity (F = D): keep the cubic finite
        c3 = (1e-12 if c3 >= 0 else -1e-12) * scale
    comp = np.zeros((3, 3), dtype=np.complex128)
    for j in range(3):
        comp[0, j] = -coeffs[j + 1] / c3
    comp[1, 0] = 1.0
    comp[2, 1] = 1.0
    roots = np.linalg.eigvals(comp)
    n = 0
    for r in roots:
        if abs(r.imag) <= 1e-8 * (1.0 + abs(r.real)):
            norm = 0.0
            for i in range(9):
                out[n, i] = f2[i] + r.real * d[i]
                norm += out[n, i] * out[n, i]
            norm = np.sqrt(norm)
            if np.isfinite(norm) and norm > 0:
                for i in range(9):
                    out[n, i] /= norm
                n += 1
    return n


@numba.njit(cache=True, nogil=True)
def seven_point_kernel(x1: np.ndarray, x2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(M, K, 2) normalised samples -> (F (<= 3M, 3, 3) unit norm, sample index of each)."""
    M, K = x1.shape[0], x1.shape[1]
    F = np.empty((3 * M, 9))
    sid = np.empty(3 * M, dtype=np.int64)
    buf = np.empty((3, 9))
    A = np.empty((K, 9))
    vander_inv = _VANDER_INV
    n = 0
    for m in range(M):
        for k in range(K):
            design_row(x1[m, k, 0], x1[m, k, 1], x2[m, k, 0], x2[m, k, 1], A[k])
        finite = True
        for k in range(K):
            for i in range(9):
                finite = finite and np.isfinite(A[k, i])
        if not finite:
            continue
        r = _seven_point_one(A, vander_inv, buf)
        for j in range(r):
            for i in range(9):
                F[n, i] = buf[j, i]
            sid[n] = m
            n += 1
    return F[:n].reshape(n, 3, 3), sid[:n]


def seven_point(x1: np.ndarray, x2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """All real-root F of M seven-point samples.

    With K > 7 correspondences per sample the two-dimensional null space is the least-squares
    one (the two smallest right singular vectors), which is exact when the rows have rank 7,
    e.g. 4 general points plus any number of points on one 3D line (they give 3 constraints).

    Args:
        x1, x2: (M, K, 2) correspondences, K >= 7 (normalised coordinates recommended).
    Returns:
        (F, sample): F (K, 3, 3) unit-norm models, K <= 3M; sample (K,) int index of the sample
        each model came from.
    """
    if x1.ndim != 3 or x1.shape[1] < 7:
        raise ValueError(f"seven_point expects (M, K >= 7, 2) inputs, got {x1.shape}")
    return seven_point_kernel(
        np.ascontiguousarray(x1, dtype=np.float64), np.ascontiguousarray(x2, dtype=np.float64)
    )
