"""F refined by Levenberg-Marquardt on the truncated symmetric epipolar error (rank 2 kept).

A linear refit (:mod:`refine`) minimises an algebraic error and then forces rank 2, so its model
is not the one of least geometric error, and on forward motion (epipole inside the image) the
gap decides which basin RANSAC ends in. This module minimises

    C(F) = sum_i min(e_i(F)^2, t^2),   e_i = (x2_i^T F x1_i) (1 / |l1_i| + 1 / |l2_i|) / 2

directly: e_i is the signed symmetric epipolar distance in px (its absolute value is what
:func:`~sepfm_ros.geometry.epipolar.symmetric_epipolar_distance` measures; l2 = F x1, l1 = F^T x2,
|l| the norm of a line's first two coordinates), t the truncation in px. F stays rank 2 on the
way: it is held as F_n = U diag(1, sigma, 0) V^T in the normalised coordinates of
:class:`~sepfm_ros.geometry.fundamental.correspondences.Correspondences` (U, V rotations: 7
parameters), and
each step solves the damped normal equations of the matches with |e_i| < t (the truncated loss's
weights are 1 inside, 0 outside). A step is taken only if it lowers C. Matches farther than
``LM_REACH`` t from the start model are held at t^2 (they are not read again).
"""

from __future__ import annotations

import numba
import numpy as np

from sepfm_ros.geometry.epipolar import (
    denormalize_unit_kernel,
    distances_within_kernel,
    msac_kernel,
)
from sepfm_ros.geometry.fundamental.correspondences import Correspondences
from sepfm_ros.geometry.solvers.cholesky import cholesky_lower, cholesky_solve
from sepfm_ros.geometry.solvers.design import FAST_MATH, column_gram

#: Levenberg-Marquardt iterations of :func:`refine_truncated` at most.
LM_ITERATIONS = 10
#: :func:`refine_truncated` stops after a step that lowers the cost by less than this share.
LM_TOLERANCE = 1e-4
#: :func:`refine_truncated` fits the matches within this many truncations of the start model.
LM_REACH = 3.0
#: :func:`noise_truncation`: the truncation is ``LM_NOISE_FACTOR`` times the median distance of
#: the matches within ``LM_BAND`` x threshold of the model, clamped to [1, ``LM_BAND``] x threshold.
LM_NOISE_FACTOR = 7.0
LM_BAND = 3.0
#: :func:`polish_local_optimization` refines the sample's own model too when the truncation is
#: at least this times the threshold (noisy matches; on precise ones it adds nothing).
LM_MODEL_START = 1.5
#: :func:`polish_final`: the final model of noisy matches is refined at this truncation, times the
#: threshold (wider than the noise truncation on forward motion, where a fit truncated nearer the
#: threshold keeps the bias of the matches it leaves out; docs/design.md)
FINAL_TRUNCATION = 2.5
#: :func:`polish_final` at wide thresholds: F is refined at ``WIDE_TRUNCATION`` x the threshold
#: when that is at least ``WIDE_MIN_PX`` px (thresholds of 3 px and more; below a pixel a fit
#: would cut true matches of sub-pixel features), and kept if its :func:`multi_scale_cost` at
#: ``WIDE_SCALES`` x the threshold is lower.
WIDE_TRUNCATION = 1.0 / 3.0
WIDE_MIN_PX = 1.0
WIDE_SCALES = (1.0 / 3.0, 0.5, 1.0)


@numba.njit(cache=True, nogil=True, inline="always")
def _matmul3(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """(3, 3) A B in scalar code (numba's ``@`` calls BLAS, whose call costs more than a 3x3
    product: the LM step's small products are most of its time on a few hundred matches)."""
    C = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            C[i, j] = A[i, 0] * B[0, j] + A[i, 1] * B[1, j] + A[i, 2] * B[2, j]
    return C


@numba.njit(cache=True, nogil=True)
def _rotated(U: np.ndarray, w0: float, w1: float, w2: float) -> np.ndarray:
    """(3, 3) U exp([w]x) (Rodrigues: exp([w]x) = I + a [w]x + b [w]x^2, [w]x^2 = w w^T - |w|^2 I;
    a = 1, b = 0 below |w| = 1e-12)."""
    th2 = w0 * w0 + w1 * w1 + w2 * w2
    th = np.sqrt(th2)
    a, b = 1.0, 0.0
    if th >= 1e-12:
        a = np.sin(th) / th
        b = (1.0 - np.cos(th)) / th2
    w = (w0, w1, w2)
    R = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            R[i, j] = b * w[i] * w[j]
        R[i, i] += 1.0 - b * th2
    R[0, 1] -= a * w2
    R[0, 2] += a * w1
    R[1, 0] += a * w2
    R[1, 2] -= a * w0
    R[2, 0] -= a * w1
    R[2, 1] += a * w0
    return _matmul3(U, R)


@numba.njit(cache=True, nogil=True)
def _solve_damped(JtJ: np.ndarray, Jte: np.ndarray, lam: float) -> np.ndarray:
    """(7,) step -(JtJ + lam diag(max(JtJ_pp, 1e-12)))^-1 Jte by Cholesky (the damped matrix is
    positive definite; np.linalg.solve if rounding says otherwise)."""
    n = JtJ.shape[0]
    A = JtJ.copy()
    for p in range(n):
        A[p, p] += lam * max(JtJ[p, p], 1e-12)
    L = np.zeros((n, n))
    if not cholesky_lower(A, 0.0, L):
        return -np.linalg.solve(A, Jte)
    step = np.empty(n)
    cholesky_solve(L, Jte, np.empty(n), step)
    return -step


@numba.njit(cache=True, nogil=True)
def _compose(U: np.ndarray, sigma: float, V: np.ndarray) -> np.ndarray:
    """(3, 3) U diag(1, sigma, 0) V^T."""
    F = np.empty((3, 3))
    for a in range(3):
        for b in range(3):
            F[a, b] = U[a, 0] * V[b, 0] + sigma * U[a, 1] * V[b, 1]
    return F


@numba.njit(cache=True, nogil=True, inline="always")
def _epipolar_terms(
    F: np.ndarray, x: float, y: float, u: float, v: float, s1: float, s2: float
) -> tuple[float, float, float, float, float, float, float]:
    """(r, l20, l21, l10, l11, q1, q2) of one normalised match (x, y) <-> (u, v) under normalised
    F (3, 3): r = x2^T F x1, l2 = F x1 and l1 = F^T x2 (first two coordinates), q = (s |l|)^2
    (s the normalising scale of the line's image, so e = r (1 / sqrt(q1) + 1 / sqrt(q2)) / 2 px)."""
    l20 = F[0, 0] * x + F[0, 1] * y + F[0, 2]
    l21 = F[1, 0] * x + F[1, 1] * y + F[1, 2]
    l22 = F[2, 0] * x + F[2, 1] * y + F[2, 2]
    l10 = F[0, 0] * u + F[1, 0] * v + F[2, 0]
    l11 = F[0, 1] * u + F[1, 1] * v + F[2, 1]
    r = u * l20 + v * l21 + l22
    q2 = s2 * s2 * (l20 * l20 + l21 * l21)
    q1 = s1 * s1 * (l10 * l10 + l11 * l11)
    return r, l20, l21, l10, l11, q1, q2


@numba.njit(cache=True, nogil=True, fastmath=FAST_MATH)
def _squared_error_within(
    F: np.ndarray, x: float, y: float, u: float, v: float, s1: float, s2: float, cap2: float
) -> float:
    """e^2 (px^2) of one normalised match under normalised F (3, 3), or inf when e^2 >= cap2
    for certain (decided without square roots: e >= |r| / max(s1 |l1|, s2 |l2|)) or an
    epipolar line is undefined."""
    r, _, _, _, _, q1, q2 = _epipolar_terms(F, x, y, u, v, s1, s2)
    if r * r >= cap2 * max(q1, q2) or q1 <= 0.0 or q2 <= 0.0:
        return np.inf
    e = 0.5 * r * (1.0 / np.sqrt(q1) + 1.0 / np.sqrt(q2))
    return e * e


@numba.njit(cache=True, nogil=True, fastmath=FAST_MATH)
def _truncated_pass(
    F: np.ndarray,
    x1: np.ndarray,
    x2: np.ndarray,
    s1: float,
    s2: float,
    t2: float,
    rows: np.ndarray,
    e_in: np.ndarray,
) -> tuple[float, int]:
    """One pass of normalised F (3, 3) over the matches x1, x2 (n, 2): the truncated cost
    sum min(e_i^2, t2) and, of the m matches with e_i^2 < t2, the rows de_i/dF (row-major F)
    into the columns rows[:, :m] (9, n) and e_i into e_in[:m]. Returns (cost, m).

    A match is beyond the truncation when r^2 >= t2 max(q1, q2) (q = (s |l|)^2: e >= |r| /
    max(s1 |l1|, s2 |l2|)); it then adds t2 without square roots or divisions.
    """
    c = 0.0
    m = 0
    for i in range(x1.shape[0]):
        x, y, u, v = x1[i, 0], x1[i, 1], x2[i, 0], x2[i, 1]
        r, l20, l21, l10, l11, q1, q2 = _epipolar_terms(F, x, y, u, v, s1, s2)
        if r * r >= t2 * max(q1, q2) or q1 <= 0.0 or q2 <= 0.0:
            c += t2  # beyond the truncation, or an undefined epipolar line (e = inf)
            continue
        i1 = 1.0 / np.sqrt(q1)  # 1 / (s1 |l1|)
        i2 = 1.0 / np.sqrt(q2)
        e = 0.5 * r * (i1 + i2)
        e2 = e * e
        if not e2 < t2:
            c += t2
            continue
        c += e2
        # de/dF_ab = c x2_a x1_b - k1 [b<2] l1_b x2_a - k2 [a<2] l2_a x1_b, with
        # c = (i1 + i2) / 2, k1 = r i1^3 s1^2 / 2, k2 = r i2^3 s2^2 / 2
        cc = 0.5 * (i1 + i2)
        k1 = 0.5 * r * i1 * i1 * i1 * s1 * s1
        k2 = 0.5 * r * i2 * i2 * i2 * s2 * s2
        m0, m1, m2 = cc * x - k1 * l10, cc * y - k1 * l11, cc  # c x1_b - k1 l1_b
        a0, a1 = k2 * l20, k2 * l21
        rows[0, m], rows[1, m], rows[2, m] = u * m0 - a0 * x, u * m1 - a0 * y, u * m2 - a0
        rows[3, m], rows[4, m], rows[5, m] = v * m0 - a1 * x, v * m1 - a1 * y, v * m2 - a1
        rows[6, m], rows[7, m], rows[8, m] = m0, m1, m2
        e_in[m] = e
        m += 1
    return c, m


@numba.njit(cache=True, nogil=True)
def _parameter_derivatives(U: np.ndarray, sigma: float, V: np.ndarray) -> np.ndarray:
    """(7, 9) dF_n / d(parameter), row-major F_n, at U diag(1, sigma, 0) V^T for
    U <- U exp([w]x), V <- V exp([z]x), sigma <- sigma + ds: parameters (w0, w1, w2, z0, z1, z2,
    ds)."""
    D = np.empty((7, 9))
    SVt = np.zeros((3, 3))  # diag(1, sigma, 0) V^T
    US = np.zeros((3, 3))  # U diag(1, sigma, 0)
    for j in range(3):
        SVt[0, j], SVt[1, j] = V[j, 0], sigma * V[j, 1]
        US[j, 0], US[j, 1] = U[j, 0], sigma * U[j, 1]
    Vt = V.T.copy()
    for k in range(3):
        E = np.zeros((3, 3))  # [e_k]x
        E[(k + 2) % 3, (k + 1) % 3] = 1.0
        E[(k + 1) % 3, (k + 2) % 3] = -1.0
        A = _matmul3(U, _matmul3(E, SVt))
        B = _matmul3(US, _matmul3(E, Vt))
        for i in range(9):
            D[k, i] = A[i // 3, i % 3]
            D[3 + k, i] = -B[i // 3, i % 3]
    for i in range(9):
        D[6, i] = U[i // 3, 1] * V[i % 3, 1]  # U diag(0, 1, 0) V^T
    return D


@numba.njit(cache=True, nogil=True)
def _normal_equations(D: np.ndarray, M: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(J^T J (7, 7), J^T e (7,)) = (D M D^T, D b) from D = dF/d(parameters) (7, 9), M = G^T G
    (9, 9) and b = G^T e (9,) of the rows G = de/dF, in scalar code."""
    DM = np.zeros((7, 9))
    JtJ = np.empty((7, 7))
    Jte = np.zeros(7)
    for p in range(7):
        for j in range(9):
            Jte[p] += D[p, j] * b[j]
            for k in range(9):
                DM[p, j] += D[p, k] * M[k, j]
    for p in range(7):
        for q in range(p, 7):
            v = 0.0
            for j in range(9):
                v += DM[p, j] * D[q, j]
            JtJ[p, q] = v
            JtJ[q, p] = v
    return JtJ, Jte


@numba.njit(cache=True, nogil=True, fastmath=FAST_MATH)
def refine_truncated_kernel(
    F: np.ndarray,
    x1: np.ndarray,
    x2: np.ndarray,
    T1: np.ndarray,
    T2: np.ndarray,
    truncation: float,
    iterations: int,
) -> np.ndarray:
    """See :func:`refine_truncated`; F and the result in px, x1, x2 normalised by T1, T2."""
    if not np.isfinite(F).all():
        return F.copy()
    s1, s2 = T1[0, 0], T2[0, 0]
    t2 = truncation * truncation
    F_n = np.linalg.inv(T2).T @ F @ np.linalg.inv(T1)
    U, sv, Vt = np.linalg.svd(F_n)
    if sv[0] <= 0.0 or not np.isfinite(sv[0]):
        return F.copy()
    V = Vt.T.copy()
    U = U.copy()
    if np.linalg.det(U) < 0:
        U = -U
    if np.linalg.det(V) < 0:
        V = -V
    # F_n ~ U diag(s0, s1, 0) V^T up to sign, which does not matter for F
    sigma = sv[1] / sv[0]
    G = _compose(U, sigma, V)
    # matches beyond LM_REACH x the truncation from the start stay out of the fit (each adds t^2
    # to the cost whatever the steps do), so every iteration reads only the matches near F
    N = x1.shape[0]
    keep = np.empty(N, dtype=np.int64)
    n = 0
    reach2 = LM_REACH * LM_REACH * t2
    for i in range(N):
        if (
            _squared_error_within(G, x1[i, 0], x1[i, 1], x2[i, 0], x2[i, 1], s1, s2, reach2)
            < reach2
        ):
            keep[n] = i
            n += 1
    x1 = x1[keep[:n]]
    x2 = x2[keep[:n]]
    held = (N - n) * t2
    # each pass scores a model and writes its rows (J_i = D g_i, g_i = de_i/dF of the matches
    # inside the truncation): the pass of an accepted step gives the next step's normal equations
    rows, e_in = np.empty((9, n)), np.empty(n)
    rows2, e_in2 = np.empty((9, n)), np.empty(n)
    cost, m = _truncated_pass(G, x1, x2, s1, s2, t2, rows, e_in)
    cost += held
    lam = 1e-3
    small = False
    for _ in range(iterations):
        # J_i = D g_i, so J^T J = D (G^T G) D^T with the rows g_i in G
        b = np.zeros(9)
        for p in range(9):
            for i in range(m):
                b[p] += rows[p, i] * e_in[i]
        JtJ, Jte = _normal_equations(_parameter_derivatives(U, sigma, V), column_gram(rows, m), b)
        if np.abs(Jte).max() < 1e-12 * max(1.0, cost):
            break
        improved = False
        while lam < 1e10:
            step = _solve_damped(JtJ, Jte, lam)
            U2 = _rotated(U, step[0], step[1], step[2])
            V2 = _rotated(V, step[3], step[4], step[5])
            sigma2 = sigma + step[6]
            G2 = _compose(U2, sigma2, V2)
            cost2, m2 = _truncated_pass(G2, x1, x2, s1, s2, t2, rows2, e_in2)
            cost2 += held
            if cost2 < cost:
                U, V, sigma, G = U2, V2, sigma2, G2
                rows, rows2, e_in, e_in2, m = rows2, rows, e_in2, e_in, m2
                small = cost - cost2 < LM_TOLERANCE * cost
                cost = cost2
                lam = max(lam / 10.0, 1e-12)
                improved = True
                break
            lam *= 10.0
        if not improved or small:
            break
    return denormalize_unit_kernel(G, T1, T2)


def refine_truncated(
    F: np.ndarray,
    data: Correspondences,
    truncation: float,
    iterations: int = LM_ITERATIONS,
) -> np.ndarray:
    """F (3, 3, px) refined to a local minimum of sum_i min(e_i^2, truncation^2) (see module).

    Args:
        F: (3, 3) start model, x2^T F x1 = 0, pixels (any rank; its closest rank-2 matrix starts).
        data: all matches (prepared once per estimate).
        truncation: px of symmetric epipolar distance beyond which a match adds a constant.
        iterations: Levenberg-Marquardt iterations at most.
    Returns:
        (3, 3) rank-2 F in px at unit Frobenius norm; never a higher cost than the start's closest
        rank-2 matrix.
    """
    return refine_truncated_kernel(
        np.ascontiguousarray(F, dtype=np.float64), data.x1, data.x2, data.T1, data.T2,
        float(truncation), int(iterations),
    )  # fmt: skip


@numba.njit(cache=True, nogil=True)
def _noise_truncation_kernel(
    F: np.ndarray, X1: np.ndarray, X2: np.ndarray, threshold: float
) -> float:
    """See :func:`noise_truncation`; X1, X2 (3, N) homogeneous pixels."""
    band = LM_BAND * threshold
    d = distances_within_kernel(F.reshape(1, 3, 3), X1, X2, band)[0]
    near = d[d < band]
    if near.shape[0] == 0:
        return threshold
    return min(max(LM_NOISE_FACTOR * np.median(near), threshold), band)


def noise_truncation(F: np.ndarray, data: Correspondences, threshold: float) -> float:
    """The truncation (px) that fits the matches' noise: ``LM_NOISE_FACTOR`` x the median
    symmetric epipolar distance of the matches within ``LM_BAND`` x ``threshold`` of F (3, 3),
    clamped to [``threshold``, ``LM_BAND`` x ``threshold``].

    Precise matches (SIFT at full resolution: median about 0.12-0.18 px) are fitted at the inlier
    threshold; noisier ones (ORB on KITTI: about 0.42 px) at up to 3x it, where a fit truncated at
    the threshold follows the noise of the matches near it.
    """
    return float(
        _noise_truncation_kernel(
            np.ascontiguousarray(F, dtype=np.float64), data.X1, data.X2, float(threshold)
        )
    )


@numba.njit(cache=True, nogil=True)
def _polish_kernel(
    model: np.ndarray,
    start: np.ndarray,
    x1: np.ndarray,
    x2: np.ndarray,
    X1: np.ndarray,
    X2: np.ndarray,
    T1: np.ndarray,
    T2: np.ndarray,
    threshold: float,
    iterations: int,
    model_start: float,
) -> np.ndarray:
    """See :func:`polish_local_optimization`."""
    t = _noise_truncation_kernel(start, X1, X2, threshold)
    both = t >= model_start * threshold  # noisy matches: the sample's model is refined too
    out = np.empty((2 if both else 1, 3, 3))
    out[0] = refine_truncated_kernel(start, x1, x2, T1, T2, t, iterations)
    if both:
        out[1] = refine_truncated_kernel(model, x1, x2, T1, T2, t, iterations)
    return out


def polish_local_optimization(
    model: np.ndarray,
    start: np.ndarray,
    data: Correspondences,
    threshold: float,
    iterations: int = LM_ITERATIONS,
) -> np.ndarray:
    """The Levenberg-Marquardt step of local optimisation (the ``"lm"`` scheme).

    ``start`` (the best of the sample's ``model`` and its least-squares refits, by MSAC cost at
    ``threshold``) is refined by :func:`refine_truncated` at the :func:`noise_truncation` of
    ``start``; when that truncation is at least ``LM_MODEL_START`` x ``threshold`` (noisy
    matches), the sample's own ``model`` is refined too. The two starts end in different minima:
    from the refits the fit keeps what they found, from the sample's model it finds the basin a
    wider truncation prefers on noisy matches, where the refits settled at the threshold. The
    caller scores the results.

    Args:
        model: (3, 3) the sample's model, px. start: (3, 3) the best of it and its refits, px.
        data: all matches. threshold: px, the inlier threshold.
    Returns:
        (K, 3, 3) rank-2 models in px, K = 1 or 2: refined from ``start``, then from ``model``.
    """
    return _polish_kernel(
        np.ascontiguousarray(model, dtype=np.float64),
        np.ascontiguousarray(start, dtype=np.float64),
        data.x1, data.x2, data.X1, data.X2, data.T1, data.T2, float(threshold), int(iterations),
        LM_MODEL_START,
    )  # fmt: skip


def multi_scale_cost(F: np.ndarray, data: Correspondences, truncations: np.ndarray) -> np.ndarray:
    """sum over t of C_t(F) / t^2, C_t the MSAC cost sum_i min(e_i^2, t^2) (px^2), for (M, 3, 3)
    models F and (T,) truncations t (px) -> (M,).

    Each term is the share of a match's error budget it uses at one scale (1 per match beyond
    t), so no scale dominates: a model that fits the true matches tightly and one that fits
    more matches loosely are weighed at every scale between the tightest truncation and the
    threshold (a sum over noise levels in the spirit of MAGSAC's marginalisation).
    """
    models = np.ascontiguousarray(F, dtype=np.float64)
    total = np.zeros(models.shape[0])
    for t in np.asarray(truncations, dtype=np.float64):
        cost, _ = msac_kernel(models, data.X1, data.X2, float(t))
        total += cost / (t * t)
    return total


def polish_final(
    F: np.ndarray, data: Correspondences, threshold: float, off_plane: np.ndarray | None = None
) -> np.ndarray:
    """The final model's Levenberg-Marquardt steps (the ``"lm"`` scheme's last refinement).

    1. Noisy matches (:func:`noise_truncation` of F at least ``LM_MODEL_START`` x ``threshold``,
       as for the second start of :func:`polish_local_optimization`): F is refined by
       :func:`refine_truncated` at ``FINAL_TRUNCATION`` x ``threshold``, and the refined model
       replaces F if it keeps at least as many matches within ``threshold``.
    2. Wide thresholds (``WIDE_TRUNCATION`` x ``threshold`` at least ``WIDE_MIN_PX``): F is
       refined at that truncation and replaced if the refined model's
       :func:`multi_scale_cost` at ``WIDE_SCALES`` x ``threshold`` is lower. A threshold far
       above the matches' noise lets the wrong matches within it pull a fit truncated there
       (pairs with few true matches); the tighter fit follows the true ones.

    The first replacement also needs as many of the ``off_plane`` matches within ``threshold``
    (a fit that trades parallax for a dominant plane's matches heads for a plane-degenerate F;
    one that follows wrong matches lying within the wider truncation, e.g. a repetitive row
    matched one period off, loses true ones at the threshold). The second does not: at a wide
    threshold the matches a tighter fit leaves out are mostly the wrong ones it is meant to
    leave out, off the plane or not.

    Args:
        F: (3, 3) the final model, px. data: all matches. threshold: px, the inlier threshold.
        off_plane: (N,) bool, the matches off a dominant plane (the plane check's), or None.
    Returns:
        (3, 3) F in px: refined (rank 2, unit norm) or ``F`` itself.
    """
    if noise_truncation(F, data, threshold) >= LM_MODEL_START * threshold:
        G = refine_truncated(F, data, FINAL_TRUNCATION * threshold)
        d = data.distances(np.ascontiguousarray(np.stack([F, G]))) < threshold
        kept = np.count_nonzero(d[1]) >= np.count_nonzero(d[0])
        if kept and off_plane is not None:
            kept = np.count_nonzero(d[1] & off_plane) >= np.count_nonzero(d[0] & off_plane)
        if kept:
            F = G
    tight = WIDE_TRUNCATION * threshold
    if tight >= WIDE_MIN_PX:
        G = refine_truncated(F, data, tight)
        cost = multi_scale_cost(np.stack([F, G]), data, np.asarray(WIDE_SCALES) * threshold)
        if np.isfinite(G).all() and cost[1] < cost[0]:
            F = G
    return F
