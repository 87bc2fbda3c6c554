"""The paper's 2x2 epipolar line homography H_e between two image lines (1D projective map).

A point on line l is written as alpha * x_1 + beta * x_2 in its two control points; H_e maps
(alpha, beta) of a point on l to (alpha', beta') of its correspondence on l', up to scale:
(alpha', beta')^T ~ H_e (alpha, beta)^T. Each correspondence gives one linear equation in
h = (a, b, c, d):  alpha' (c alpha + d beta) - beta' (a alpha + b beta) = 0.
"""

from __future__ import annotations

import numba
import numpy as np


def _rows(ab1: np.ndarray, ab2: np.ndarray) -> np.ndarray:
    """(..., K, 2) x 2 -> (..., K, 4) rows of the H_e equations."""
    a1, b1 = ab1[..., 0], ab1[..., 1]
    a2, b2 = ab2[..., 0], ab2[..., 1]
    return np.stack([-b2 * a1, -b2 * b1, a2 * a1, a2 * b1], axis=-1)


def line_homography_3pt(ab1: np.ndarray, ab2: np.ndarray) -> np.ndarray:
    """Minimal solver: H_e from 3 correspondences of 1D projective points, batched.

    Args:
        ab1, ab2: (M, 3, 2) (alpha, beta) coordinates of the points on line 1 and line 2.
    Returns:
        (M, 2, 2) H_e with unit Frobenius norm (the null vector of the 3x4 system).
    """
    A = _rows(ab1, ab2)
    A = np.concatenate([A, np.zeros(A.shape[:-2] + (1, 4))], axis=-2)
    _, _, Vt = np.linalg.svd(A)
    return Vt[..., -1, :].reshape(*A.shape[:-2], 2, 2)


def line_homography_lsq(ab1: np.ndarray, ab2: np.ndarray) -> np.ndarray:
    """Least-squares H_e from K >= 3 correspondences: ab1, ab2 (K, 2) -> (2, 2)."""
    A = _rows(ab1, ab2)
    _, _, Vt = np.linalg.svd(A)
    return Vt[-1].reshape(2, 2)


def transfer(H: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Map line parameters t (point = c_1 + t (c_2 - c_1), i.e. (alpha, beta) = (1 - t, t)).

    Args:
        H: (M, 2, 2) or (2, 2) line homographies.
        t: (N,) parameters on line 1.
    Returns:
        (M, N) or (N,) parameters t' on line 2 (inf where the image point is at infinity).
    """
    H = np.asarray(H, dtype=np.float64)
    single = H.ndim == 2
    Hs = H[None] if single else H
    # (alpha', beta') = H (1 - t, t): linear in t
    a = Hs[:, 0, 0, None] + (Hs[:, 0, 1, None] - Hs[:, 0, 0, None]) * t
    b = Hs[:, 1, 0, None] + (Hs[:, 1, 1, None] - Hs[:, 1, 0, None]) * t
    den = a + b
    with np.errstate(divide="ignore", invalid="ignore"):
        tp = b / den
    tp = np.where(np.isfinite(tp), tp, np.inf)
    return tp[0] if single else tp


# --------------------------------------------------------------------------------------------
# Scalar kernels for the compiled stage-1 loop (separable.stage1.stage1_ransac).
# H is held as h = (a, b, c, d) for [[a, b], [c, d]].
# --------------------------------------------------------------------------------------------


@numba.njit(cache=True, nogil=True, inline="always")
def _row_kernel(t1: float, t2: float, row: np.ndarray) -> None:
    """Row (4,) of :func:`_rows` for line parameters t1 -> t2 ((alpha, beta) = (1 - t, t))."""
    a1, b1, a2, b2 = 1.0 - t1, t1, 1.0 - t2, t2
    row[0], row[1], row[2], row[3] = -b2 * a1, -b2 * b1, a2 * a1, a2 * b1


@numba.njit(cache=True, nogil=True)
def line_homography_3pt_kernel(t1: np.ndarray, t2: np.ndarray, out: np.ndarray) -> None:
    """Minimal solver on line parameters: 3 correspondences t1[i] -> t2[i] into out (4,).

    The null vector of the 3x4 system (rows of :func:`_rows` at (alpha, beta) = (1 - t, t)) by
    cofactors, unit norm (the same H_e as :func:`line_homography_3pt`, up to sign).
    """
    A = np.empty((3, 4))
    for i in range(3):
        _row_kernel(t1[i], t2[i], A[i])
    sign = 1.0
    norm = 0.0
    for j in range(4):
        # 3x3 determinant of A without column j
        c0 = 1 if j == 0 else 0
        c1 = 2 if j <= 1 else 1
        c2 = 3 if j <= 2 else 2
        det = (
            A[0, c0] * (A[1, c1] * A[2, c2] - A[1, c2] * A[2, c1])
            - A[0, c1] * (A[1, c0] * A[2, c2] - A[1, c2] * A[2, c0])
            + A[0, c2] * (A[1, c0] * A[2, c1] - A[1, c1] * A[2, c0])
        )
        out[j] = sign * det
        norm += det * det
        sign = -sign
    norm = np.sqrt(norm)
    for j in range(4):
        out[j] = out[j] / norm if norm > 0.0 else 0.0


@numba.njit(cache=True, nogil=True)
def line_homography_lsq_kernel(t1: np.ndarray, t2: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Least-squares H_e (4,) on the correspondences where mask is True (unit norm).

    The smallest right singular vector of the K x 4 system, as :func:`line_homography_lsq`.
    """
    k = 0
    for i in range(len(t1)):
        if mask[i]:
            k += 1
    A = np.empty((k, 4))
    r = 0
    for i in range(len(t1)):
        if mask[i]:
            _row_kernel(t1[i], t2[i], A[r])
            r += 1
    _, _, vt = np.linalg.svd(A, full_matrices=False)
    return vt[3].copy()


@numba.njit(cache=True, nogil=True)
def transfer_kernel(a: float, b: float, c: float, d: float, t: float) -> float:
    """t' of t under H = [[a, b], [c, d]] ((alpha, beta) = (1 - t, t)); inf at infinity."""
    alpha = a + (b - a) * t
    beta = c + (d - c) * t
    den = alpha + beta
    if den == 0.0:
        return np.inf
    tp = beta / den
    if not np.isfinite(tp):
        return np.inf
    return tp
