"""The epipolar design row shared by the seven- and eight-point solvers and the refits, and the
Gram matrix of many rows shared by the refits and the Levenberg-Marquardt step."""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True, inline="always")
def design_row(x: float, y: float, u: float, v: float, r: np.ndarray) -> None:
    """Write into r (9,) the row of x2^T F x1 = 0 in vec(F) (row-major) for (x, y) <-> (u, v).

    r = kron([u, v, 1], [x, y, 1]).
    """
    r[0], r[1], r[2] = u * x, u * y, u
    r[3], r[4], r[5] = v * x, v * y, v
    r[6], r[7], r[8] = x, y, 1.0


#: floating-point liberties of the kernels that sum over all matches: reordered sums (which
#: vectorise) and fused multiply-adds; infinities and NaN keep their meaning
FAST_MATH = {"reassoc", "contract", "arcp", "nsz"}


@numba.njit(cache=True, nogil=True, fastmath=FAST_MATH)
def column_gram(R: np.ndarray, m: int) -> np.ndarray:
    """(9, 9) R[:, :m] R[:, :m]^T of the rows stored as the columns of R (9, n), one per match.

    Each entry is one sum over the matches, which ``FAST_MATH`` lets the compiler vectorise
    (a 9 x 9 outer product per match, or a BLAS product of a 9-column matrix, costs a few
    times as much).
    """
    G = np.empty((9, 9))
    for p in range(9):
        for q in range(p, 9):
            acc = 0.0
            for i in range(m):
                acc += R[p, i] * R[q, i]
            G[p, q] = acc
            G[q, p] = acc
    return G


@numba.njit(cache=True, nogil=True, inline="always")
def add_outer(G: np.ndarray, r: np.ndarray, weight: float) -> None:
    """G (9, 9) upper triangle += weight r r^T (symmetrise with :func:`symmetrize` at the end)."""
    for p in range(9):
        rp = r[p] * weight
        for q in range(p, 9):
            G[p, q] += rp * r[q]


@numba.njit(cache=True, nogil=True, inline="always")
def symmetrize(G: np.ndarray) -> None:
    """Copy the upper triangle of G (9, 9) to the lower."""
    for p in range(9):
        for q in range(p):
            G[p, q] = G[q, p]


@numba.njit(cache=True, nogil=True)
def null_basis(A: np.ndarray, basis: np.ndarray) -> bool:
    """Orthonormal basis of the null space of A (K, 9), K < 9 rows of full rank K.

    Gauss-Jordan elimination with full pivoting (a few microseconds for a minimal sample, against
    tens for an SVD or a Gram-matrix eigen-decomposition).

    Args:
        A: (K, 9) design rows (normalised coordinates). basis: (9 - K, 9) output rows.
    Returns:
        False when a pivot vanishes (rank < K: a degenerate sample; ``basis`` is undefined).
    """
    K = A.shape[0]
    M = A.copy()
    perm = np.arange(9)
    scale = 0.0
    for i in range(K):
        for j in range(9):
            scale = max(scale, abs(M[i, j]))
    if not (scale > 0 and np.isfinite(scale)):
        return False
    for r in range(K):
        best, pi, pj = 0.0, r, r
        for i in range(r, K):
            for j in range(r, 9):
                v = abs(M[i, j])
                if v > best:
                    best, pi, pj = v, i, j
        if best <= 1e-10 * scale:
            return False
        if pi != r:
            for j in range(9):
                M[r, j], M[pi, j] = M[pi, j], M[r, j]
        if pj != r:
            for i in range(K):
                M[i, r], M[i, pj] = M[i, pj], M[i, r]
            perm[r], perm[pj] = perm[pj], perm[r]
        piv = M[r, r]
        for j in range(r, 9):
            M[r, j] /= piv
        for i in range(K):
            if i != r:
                f = M[i, r]
                if f != 0.0:
                    for j in range(r, 9):
                        M[i, j] -= f * M[r, j]
    # M = [I | B] in permuted columns: null vector q has 1 at free column K + q, -B[:, q] above
    for q in range(9 - K):
        for j in range(9):
            basis[q, j] = 0.0
        basis[q, perm[K + q]] = 1.0
        for r in range(K):
            basis[q, perm[r]] = -M[r, K + q]
    for q in range(9 - K):  # Gram-Schmidt
        for p in range(q):
            d = 0.0
            for j in range(9):
                d += basis[q, j] * basis[p, j]
            for j in range(9):
                basis[q, j] -= d * basis[p, j]
        n = 0.0
        for j in range(9):
            n += basis[q, j] * basis[q, j]
        n = np.sqrt(n)
        for j in range(9):
            basis[q, j] /= n
    return True
