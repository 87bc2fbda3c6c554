"""Cholesky factorisation and solve of small symmetric positive definite systems, compiled
(the LM step's damped 7x7 normal equations, the refits' 9x9 inverse iteration): scalar loops,
without a LAPACK call per solve. Inlined into their callers, which compile them exactly as their
own loops (same rounding)."""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True, inline="always")
def cholesky_lower(A: np.ndarray, shift: float, L: np.ndarray) -> bool:
    """Write into L (n, n) the lower factor of A + shift I (A (n, n) symmetric): L L^T.

    Returns False when a pivot is not positive (A + shift I not positive definite to rounding);
    L is then undefined. Only the lower triangle of L is written.
    """
    n = A.shape[0]
    for j in range(n):
        d = A[j, j] + shift
        for k in range(j):
            d -= L[j, k] * L[j, k]
        if not d > 0.0:
            return False
        L[j, j] = np.sqrt(d)
        for i in range(j + 1, n):
            t = A[i, j]
            for k in range(j):
                t -= L[i, k] * L[j, k]
            L[i, j] = t / L[j, j]
    return True


@numba.njit(cache=True, nogil=True, inline="always")
def cholesky_solve(L: np.ndarray, b: np.ndarray, y: np.ndarray, out: np.ndarray) -> None:
    """out (n,) = (L L^T)^-1 b (b (n,)) by the two triangular solves L y = b, L^T out = y;
    y (n,) work space."""
    n = L.shape[0]
    for i in range(n):
        t = b[i]
        for k in range(i):
            t -= L[i, k] * y[k]
        y[i] = t / L[i, i]
    for i in range(n - 1, -1, -1):
        t = y[i]
        for k in range(i + 1, n):
            t -= L[k, i] * out[k]
        out[i] = t / L[i, i]
