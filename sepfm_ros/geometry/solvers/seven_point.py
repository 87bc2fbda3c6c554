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
    roots = np.empty(3)
    n_roots = real_cubic_roots(c3, coeffs[1], coeffs[2], coeffs[3], roots)
    n = 0
    for k in range(n_roots):
        r = roots[k]
        norm = 0.0
        for i in range(9):
            out[n, i] = f2[i] + r * d[i]
            norm += out[n, i] * out[n, i]
        norm = np.sqrt(norm)
        if np.isfinite(norm) and norm > 0:
            for i in range(9):
                out[n, i] /= norm
            n += 1
    return n


@numba.njit(cache=True, nogil=True)
def _companion_roots(c3: float, c2: float, c1: float, c0: float, out: np.ndarray) -> int:
    """Real roots of c3 s^3 + c2 s^2 + c1 s + c0 (c3 != 0) as eigenvalues of the companion
    matrix (imaginary part at most 1e-8 (1 + |re|)) into out (3,); returns how many."""
    comp = np.zeros((3, 3), dtype=np.complex128)
    comp[0, 0], comp[0, 1], comp[0, 2] = -c2 / c3, -c1 / c3, -c0 / c3
    comp[1, 0] = 1.0
    comp[2, 1] = 1.0
    n = 0
    for r in np.linalg.eigvals(comp):
        if abs(r.imag) <= 1e-8 * (1.0 + abs(r.real)):
            out[n] = r.real
            n += 1
    return n


@numba.njit(cache=True, nogil=True)
def real_cubic_roots(c3: float, c2: float, c1: float, c0: float, out: np.ndarray) -> int:
    """Real roots of c3 s^3 + c2 s^2 + c1 s + c0 (c3 != 0) into out (3,); returns how many.

    Closed form (Cardano for one real root, the trigonometric form for three) of the monic
    cubic, each root polished by Newton steps on the cubic as long as they lower its residual.
    A near-double root counts as two roots only when the discriminant says three real roots.
    When c3 is tiny against the other coefficients (a root near infinity, where the closed
    form loses the small roots to cancellation) the companion matrix's eigenvalues are used.
    """
    big = max(abs(c2), abs(c1), abs(c0))
    if abs(c3) < 1e-6 * big:
        return _companion_roots(c3, c2, c1, c0, out)
    a, b, c = c2 / c3, c1 / c3, c0 / c3
    a3 = a / 3.0
    p = b - a * a3  # t^3 + p t + q = 0 with s = t - a / 3
    q = 2.0 * a3 * a3 * a3 - a3 * b + c
    hq, tp = 0.5 * q, p / 3.0
    disc = hq * hq + tp * tp * tp
    n = 0
    if disc > 0.0:
        u = np.cbrt(-hq - np.copysign(np.sqrt(disc), hq))  # no cancellation
        out[0] = (u - tp / u if u != 0.0 else 0.0) - a3
        n = 1
    elif tp == 0.0:
        out[0] = -a3
        n = 1
    else:
        m = 2.0 * np.sqrt(-tp)
        cos3 = min(1.0, max(-1.0, 3.0 * q / (p * m)))
        phi = np.arccos(cos3) / 3.0
        for k in range(3):
            out[k] = m * np.cos(phi - 2.0 * np.pi * k / 3.0) - a3
        n = 3
    for k in range(n):  # Newton polish on the monic cubic
        s = out[k]
        f = ((s + a) * s + b) * s + c
        for _ in range(2):
            df = (3.0 * s + 2.0 * a) * s + b
            if df == 0.0:
                break
            t = s - f / df
            ft = ((t + a) * t + b) * t + c
            if not abs(ft) < abs(f):
                break
            s, f = t, ft
        out[k] = s
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
