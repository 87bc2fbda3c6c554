"""Line planes: stage 2's in-sample plane check (option ``sample_plane_check``).

Three collinear correspondences (the fixed line points) fix 5 of a plane homography's 8 degrees
of freedom; two more points of a sample on one plane with the line fix the rest but one, so a
sample two of whose points share a plane with the line is plane-degenerate and is rejected
before it is solved.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["line_plane_basis", "line_plane_degenerate", "plane_free_samples"]


@numba.njit(cache=True, nogil=True, inline="always")
def _det3(S: np.ndarray, r0: int, r1: int, r2: int, c0: int, c1: int, c2: int) -> float:
    return (
        S[r0, c0] * (S[r1, c1] * S[r2, c2] - S[r1, c2] * S[r2, c1])
        - S[r0, c1] * (S[r1, c0] * S[r2, c2] - S[r1, c2] * S[r2, c0])
        + S[r0, c2] * (S[r1, c0] * S[r2, c1] - S[r1, c1] * S[r2, c0])
    )


#: rows / columns kept in the 3x3 minors of a 4x4 matrix, by the one left out
_MINOR = np.array([[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]])


@numba.njit(cache=True, nogil=True)
def _point_gram(N: np.ndarray, x: np.ndarray, u: np.ndarray, G: np.ndarray, r: np.ndarray) -> None:
    """G (4, 4) = A^T A of the two DLT rows A (2, 4) of match x -> u in the basis N (9, 4);
    r: (2, 4) work space."""
    r[:] = 0.0
    row0 = (x[0], x[1], 1.0, 0.0, 0.0, 0.0, -u[0] * x[0], -u[0] * x[1], -u[0])
    row1 = (0.0, 0.0, 0.0, x[0], x[1], 1.0, -u[1] * x[0], -u[1] * x[1], -u[1])
    for m in range(4):
        for i in range(9):
            r[0, m] += row0[i] * N[i, m]
            r[1, m] += row1[i] * N[i, m]
    for m in range(4):
        for q in range(4):
            G[m, q] = r[0, m] * r[0, q] + r[1, m] * r[1, q]


@numba.njit(cache=True, nogil=True)
def _pair_plane_error(
    N: np.ndarray,
    Gi: np.ndarray,
    Gj: np.ndarray,
    xi: np.ndarray,
    ui: np.ndarray,
    xj: np.ndarray,
    uj: np.ndarray,
    S: np.ndarray,
    h: np.ndarray,
    H: np.ndarray,
) -> float:
    """Larger transfer error (image 2's units) of two matches under the least-squares
    homography H = N h through them (``line_plane_basis``); h is the smallest eigenvector of
    the 4x4 S = Gi + Gj, taken as the adjugate's largest column (S is near singular exactly
    when the pair shares a plane with the line). S (4, 4), h (4,), H (9,): work space."""
    for m in range(4):
        for q in range(4):
            S[m, q] = Gi[m, q] + Gj[m, q]
    idx = _MINOR
    best, col = -1.0, 0
    for m in range(4):  # diagonal cofactors: the largest picks the column
        c = _det3(S, idx[m, 0], idx[m, 1], idx[m, 2], idx[m, 0], idx[m, 1], idx[m, 2])
        if c > best:
            best, col = c, m
    if not best > 0:
        return 0.0  # rank <= 2: the pair does not fix H (coincident points); degenerate
    for r in range(4):  # adj(S)[r, col] = (-1)^(r + col) minor(col, r)
        sign = 1.0 if (r + col) % 2 == 0 else -1.0
        rr, cc = idx[col], idx[r]
        h[r] = sign * _det3(S, rr[0], rr[1], rr[2], cc[0], cc[1], cc[2])
    H[:] = 0.0
    for i in range(9):
        for m in range(4):
            H[i] += N[i, m] * h[m]
    err = 0.0
    for x, u in ((xi, ui), (xj, uj)):
        w = H[6] * x[0] + H[7] * x[1] + H[8]
        if w == 0.0:
            return np.inf
        du = (H[0] * x[0] + H[1] * x[1] + H[2]) / w - u[0]
        dv = (H[3] * x[0] + H[4] * x[1] + H[5]) / w - u[1]
        e = np.sqrt(du * du + dv * dv)
        if not np.isfinite(e):
            return np.inf
        err = max(err, e)
    return err


@numba.njit(cache=True, nogil=True)
def line_plane_degenerate(
    N: np.ndarray, x1: np.ndarray, x2: np.ndarray, sample: np.ndarray, tol: float
) -> bool:
    """True when some two points of ``sample`` share a plane with the line whose homographies
    span ``N`` (9, 4) (see :func:`line_plane_basis`): both points' transfer errors under the
    pair's least-squares homography below ``tol`` (image 2's normalised units).

    3 collinear correspondences fix 5 of a plane homography's 8 degrees of freedom and 2 more
    points fix 4, so one is left over to test.
    """
    k = sample.shape[0]
    G = np.empty((k, 4, 4))
    r = np.empty((2, 4))
    S = np.empty((4, 4))
    h = np.empty(4)
    H = np.empty(9)
    for i in range(k):
        _point_gram(N, x1[sample[i]], x2[sample[i]], G[i], r)
    for i in range(k):
        for j in range(i + 1, k):
            p, q = sample[i], sample[j]
            if _pair_plane_error(N, G[i], G[j], x1[p], x2[p], x1[q], x2[q], S, h, H) < tol:
                return True
    return False


def line_plane_basis(f1: np.ndarray, f2: np.ndarray) -> np.ndarray:
    """(9, 4): an orthonormal basis (row-major H) of the homographies that map the (f >= 3, 2)
    collinear correspondences f1 -> f2 (least squares: the 4 smallest right singular vectors of
    their DLT rows), for the in-sample plane check."""
    rows = []
    for (x, y), (u, v) in zip(f1, f2, strict=True):
        rows.append([x, y, 1.0, 0.0, 0.0, 0.0, -u * x, -u * y, -u])
        rows.append([0.0, 0.0, 0.0, x, y, 1.0, -v * x, -v * y, -v])
    _, _, Vt = np.linalg.svd(np.asarray(rows), full_matrices=True)
    return np.ascontiguousarray(Vt[-4:].T)


@numba.njit(cache=True, nogil=True)
def plane_free_samples(
    N: np.ndarray, x1: np.ndarray, x2: np.ndarray, samples: np.ndarray, tol: float
) -> np.ndarray:
    """(K,) indices of the rows of (B, k) ``samples`` in which no two points share a plane with
    the line whose homographies span ``N`` (9, 4) (:func:`line_plane_degenerate` at ``tol``,
    image 2's normalised units); x1, x2: (N, 2) normalised coordinates."""
    B = samples.shape[0]
    keep = np.empty(B, dtype=np.int64)
    n_keep = 0
    for b in range(B):
        if line_plane_degenerate(N, x1, x2, samples[b], tol):
            continue
        keep[n_keep] = b
        n_keep += 1
    return keep[:n_keep]
