"""Epipolar helpers: distances, normalisation, F from cameras. Batched numpy, no ROS."""

from __future__ import annotations

import math

import numba
import numpy as np


def homogeneous(pts: np.ndarray) -> np.ndarray:
    """(N, 2) -> (N, 3) with a trailing 1."""
    return np.concatenate([pts, np.ones((pts.shape[0], 1))], axis=1)


def homogeneous_columns(pts: np.ndarray) -> np.ndarray:
    """(N, 2) -> (3, N) C-contiguous columns (x, y, 1): the layout of the compiled distances."""
    out = np.empty((3, pts.shape[0]))
    out[0] = pts[:, 0]
    out[1] = pts[:, 1]
    out[2] = 1.0
    return out


def skew(v: np.ndarray) -> np.ndarray:
    """(3,) -> (3, 3) cross-product matrix [v]_x."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def normalize_fundamental(F: np.ndarray) -> np.ndarray:
    """Scale F (..., 3, 3) to unit Frobenius norm with its largest-magnitude entry positive."""
    F = np.asarray(F, dtype=np.float64)
    if F.ndim == 2:  # one model: the same arithmetic on Python floats (several times faster)
        flat1 = F.reshape(9)
        norm1 = math.sqrt(float(np.add.reduce(flat1 * flat1)))
        top = float(flat1[int(np.argmax(np.abs(flat1)))])
        sign1 = -1.0 if top < 0.0 else (1.0 if top >= 0.0 else math.nan)
        return (flat1 * sign1 / (norm1 if norm1 != 0.0 else 1.0)).reshape(3, 3)
    flat = F.reshape(*F.shape[:-2], 9)
    norm = np.linalg.norm(flat, axis=-1, keepdims=True)
    idx = np.argmax(np.abs(flat), axis=-1)[..., None]
    sign = np.sign(np.take_along_axis(flat, idx, axis=-1))
    sign = np.where(sign == 0, 1.0, sign)
    return (flat * sign / np.where(norm == 0, 1.0, norm)).reshape(F.shape)


def _epipolar_terms(
    F: np.ndarray, X1: np.ndarray, X2: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-model algebraic residuals and the first two coordinates of the epipolar lines.

    F: (M, 3, 3); X1, X2: (3, N) homogeneous points. Returns (r, l2, l1): r (M, N) =
    x2^T F x1, l2 (M, 3, N) = F x1 (lines in image 2), l1 (M, 2, N) = first two rows of F^T x2.
    """
    M, N = F.shape[0], X1.shape[1]
    l2 = (F.reshape(-1, 3) @ X1).reshape(M, 3, N)
    l1 = (np.ascontiguousarray(F.transpose(0, 2, 1)[:, :2]).reshape(-1, 3) @ X2).reshape(M, 2, N)
    r = l2[:, 0] * X2[0] + l2[:, 1] * X2[1] + l2[:, 2]
    return r, l2, l1


@numba.njit(cache=True, nogil=True, fastmath=False)
def _distance_one(f: np.ndarray, x: float, y: float, u: float, v: float) -> float:
    """Symmetric epipolar distance (px) of one correspondence (x, y) <-> (u, v) under F (3, 3)."""
    return _distance_within(f, x, y, u, v, np.inf)


#: Relative margin of :func:`_distance_within`'s cheap test (far above the rounding of d).
_WITHIN_MARGIN = 1.0 + 1e-9


@numba.njit(cache=True, nogil=True, fastmath=False)
def _distance_within(f: np.ndarray, x: float, y: float, u: float, v: float, cap2: float) -> float:
    """:func:`_distance_one`, or inf when the distance is certainly at least cap px.

    d = |r| (1 / sqrt(n2) + 1 / sqrt(n1)) / 2 >= |r| / sqrt(max(n1, n2)) (r = x2^T F x1, n the
    squared line normals), so r^2 >= cap2 max(n1, n2), cap2 = cap^2 (1 + 1e-9), puts d above
    ``cap`` by far more than its rounding: such a point is decided without square roots or
    divisions, and every comparison ``d < t`` with t <= cap comes out as with the exact d.
    """
    a2 = f[0, 0] * x + f[0, 1] * y + f[0, 2]
    b2 = f[1, 0] * x + f[1, 1] * y + f[1, 2]
    c2 = f[2, 0] * x + f[2, 1] * y + f[2, 2]
    a1 = f[0, 0] * u + f[1, 0] * v + f[2, 0]
    b1 = f[0, 1] * u + f[1, 1] * v + f[2, 1]
    n2 = a2 * a2 + b2 * b2
    n1 = a1 * a1 + b1 * b1
    r = a2 * u + b2 * v + c2
    if r * r >= cap2 * max(n1, n2):
        return np.inf
    if n2 <= 0.0 or n1 <= 0.0:
        return np.inf
    d = 0.5 * abs(r) * (1.0 / np.sqrt(n2) + 1.0 / np.sqrt(n1))
    return d if np.isfinite(d) else np.inf


@numba.njit(cache=True, nogil=True)
def distances_within_kernel(
    F: np.ndarray, X1: np.ndarray, X2: np.ndarray, cap: float
) -> np.ndarray:
    """:func:`distances_kernel` with inf for the distances certainly at least ``cap`` px (see
    :func:`_distance_within`): the same answers to every ``d < t`` with t <= cap, cheaper."""
    M, N = F.shape[0], X1.shape[1]
    cap2 = cap * cap * _WITHIN_MARGIN
    out = np.empty((M, N))
    for m in range(M):
        f = F[m]
        for i in range(N):
            out[m, i] = _distance_within(f, X1[0, i], X1[1, i], X2[0, i], X2[1, i], cap2)
    return out


@numba.njit(cache=True, nogil=True)
def paired_hits_kernel(
    F: np.ndarray, X1: np.ndarray, X2: np.ndarray, i1: np.ndarray, i2: np.ndarray, threshold: float
) -> int:
    """How many pairings (X1[:, i1[p]], X2[:, i2[p]]) of (>=2, N) pixel points lie within
    ``threshold`` px (symmetric epipolar distance) of F (3, 3); i1, i2: (P,) int indices."""
    cap2 = threshold * threshold * _WITHIN_MARGIN
    hits = 0
    for p in range(i1.shape[0]):
        a, b = i1[p], i2[p]
        if _distance_within(F, X1[0, a], X1[1, a], X2[0, b], X2[1, b], cap2) < threshold:
            hits += 1
    return hits


@numba.njit(cache=True, nogil=True)
def distances_kernel(F: np.ndarray, X1: np.ndarray, X2: np.ndarray) -> np.ndarray:
    """(M, 3, 3) models, (>=2, N) pixel points -> (M, N) symmetric epipolar distances (px)."""
    M, N = F.shape[0], X1.shape[1]
    out = np.empty((M, N))
    for m in range(M):
        f = F[m]
        for i in range(N):
            out[m, i] = _distance_one(f, X1[0, i], X1[1, i], X2[0, i], X2[1, i])
    return out


@numba.njit(cache=True, nogil=True)
def msac_cost(
    f: np.ndarray, X1: np.ndarray, X2: np.ndarray, threshold: float, stop_at: float
) -> tuple[float, int]:
    """MSAC score of one model f (3, 3) on (>=2, N) pixel points, summed in index order: (cost,
    sum of min(d^2, t^2); inlier count, d < t), d in px. The sum stops as soon as it reaches
    ``stop_at`` (inf: never), returning the partial cost and count."""
    t2 = threshold * threshold
    cap2 = t2 * _WITHIN_MARGIN
    c = 0.0
    k = 0
    for i in range(X1.shape[1]):
        d = _distance_within(f, X1[0, i], X1[1, i], X2[0, i], X2[1, i], cap2)
        if d < threshold:
            c += d * d
            k += 1
        else:
            c += t2
        if c >= stop_at:
            break
    return c, k


@numba.njit(cache=True, nogil=True, error_model="numpy")
def point_costs(
    f: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    u: np.ndarray,
    v: np.ndarray,
    lo: int,
    hi: int,
    threshold: float,
    e: np.ndarray,
    inlier: np.ndarray,
) -> int:
    """MSAC terms of points lo .. hi - 1 under one model f (3, 3): e[i] = min(d^2, t^2) (d < t:
    d^2, else t^2), inlier[i] = d < t, for the pixel points (x[i], y[i]) <-> (u[i], v[i]) ((N,)
    rows); returns how many are inliers.

    Branch-free (numpy's error model: a zero line normal gives inf, not an exception), so the
    compiler vectorises it; d is :func:`_distance_one`'s arithmetic, so every term and every
    ``d < t`` is the same to the bit (the cheap test of :func:`_distance_within` only ever turns
    a distance above the threshold into inf)."""
    f00, f01, f02 = f[0, 0], f[0, 1], f[0, 2]
    f10, f11, f12 = f[1, 0], f[1, 1], f[1, 2]
    f20, f21, f22 = f[2, 0], f[2, 1], f[2, 2]
    t2 = threshold * threshold
    k = 0
    for i in range(lo, hi):
        xi, yi, ui, vi = x[i], y[i], u[i], v[i]
        a2 = f00 * xi + f01 * yi + f02
        b2 = f10 * xi + f11 * yi + f12
        c2 = f20 * xi + f21 * yi + f22
        a1 = f00 * ui + f10 * vi + f20
        b1 = f01 * ui + f11 * vi + f21
        n2 = a2 * a2 + b2 * b2
        n1 = a1 * a1 + b1 * b1
        r = a2 * ui + b2 * vi + c2
        d = 0.5 * abs(r) * (1.0 / np.sqrt(n2) + 1.0 / np.sqrt(n1))
        ok = d < threshold
        e[i] = d * d if ok else t2
        inlier[i] = ok
        k += ok
    return k


@numba.njit(cache=True, nogil=True)
def _msac_all(
    f: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    u: np.ndarray,
    v: np.ndarray,
    threshold: float,
    e: np.ndarray,
    inlier: np.ndarray,
) -> tuple[float, int]:
    """(MSAC cost summed in index order, inlier count) of one model f (3, 3) over every point
    (rows x, y, u, v (N,)); e, inlier (N,): the scratch of :func:`point_costs`."""
    N = x.shape[0]
    k = point_costs(f, x, y, u, v, 0, N, threshold, e, inlier)
    c = 0.0
    for i in range(N):
        c += e[i]
    return c, k


@numba.njit(cache=True, nogil=True)
def msac_kernel(
    F: np.ndarray, X1: np.ndarray, X2: np.ndarray, threshold: float
) -> tuple[np.ndarray, np.ndarray]:
    """MSAC score of (M, 3, 3) models on (>=2, N) pixel points without an (M, N) temporary.

    Returns (cost (M,), sum of min(d^2, t^2) in index order; inlier count (M,), d < t), d in px:
    :func:`msac_cost`'s values to the bit, from the vectorised :func:`point_costs`.
    """
    M, N = F.shape[0], X1.shape[1]
    cost = np.empty(M)
    count = np.zeros(M, dtype=np.int64)
    e = np.empty(N)
    inlier = np.empty(N, dtype=np.bool_)
    x, y, u, v = X1[0], X1[1], X2[0], X2[1]
    for m in range(M):
        cost[m], count[m] = _msac_all(F[m], x, y, u, v, threshold, e, inlier)
    return cost, count


def reading_copy(X1: np.ndarray, X2: np.ndarray, order: np.ndarray) -> np.ndarray:
    """(4, N) C-contiguous rows x, y, u, v of the pixel points (X1, X2 (>=2, N)) in ``order``:
    what :func:`sprt_msac_kernel` reads (made once per data and order, not per call)."""
    out = np.empty((4, X1.shape[1]))
    out[0], out[1] = X1[0, order], X1[1, order]
    out[2], out[3] = X2[0, order], X2[1, order]
    return out


#: points :func:`sprt_msac_kernel` reads one at a time before it scores the rest a chunk at a
#: time (most models of a bad sample are rejected within the first few points), and the chunk
_SINGLY, _CHUNK = 32, 128


@numba.njit(cache=True, nogil=True)
def sprt_msac_kernel(
    F: np.ndarray,
    X1: np.ndarray,
    X2: np.ndarray,
    threshold: float,
    order: np.ndarray,
    ordered: np.ndarray,
    log_A: float,
    log_in: float,
    log_out: float,
    bail_cost: float,
    bail_count: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """MSAC score of (M, 3, 3) models with early rejection (SPRT and a bail-out).

    Points are read in ``order`` (a permutation of range(N)); ``ordered`` (4, N) holds them in
    that order (:func:`reading_copy`). SPRT (Matas & Chum): the log likelihood ratio grows by
    ``log_in`` = log(delta / epsilon) per inlier and ``log_out`` = log((1 - delta) / (1 -
    epsilon)) per outlier; the model is rejected as soon as it exceeds ``log_A`` (pass inf to
    disable). Bail-out: rejected as soon as its partial cost reaches ``bail_cost`` while even
    all unread points being inliers would keep its count below ``bail_count`` (pass inf / 0 to
    disable), and its partial cost exceeds the full cost of an earlier model of this call; such
    a model can neither beat ``bail_cost``, nor reach ``bail_count``, nor be this call's
    cheapest model, so the bail-out never changes what a caller deciding by those bounds and by
    the cheapest model decides.

    The first ``_SINGLY`` points are read one at a time, the rest computed a chunk at a time
    (:func:`point_costs`, vectorised) and checked one by one: a model is rejected at the same
    point either way.

    Returns (cost (M,), inf when rejected, else exactly :func:`msac_kernel`'s cost (summed in
    index order); inlier count (M,), of the points read when rejected; points read (M,);
    rejected by SPRT (M,) bool). A model rejected by the bail-out has cost inf and rejected False.
    """
    M, N = F.shape[0], X1.shape[1]
    t2 = threshold * threshold
    cap2 = t2 * _WITHIN_MARGIN
    cost = np.empty(M)
    count = np.zeros(M, dtype=np.int64)
    read = np.zeros(M, dtype=np.int64)
    rejected = np.zeros(M, dtype=np.bool_)
    per_point = np.empty(N)  # terms in index order, for the sum
    e = np.empty(N)  # terms and inlier flags in reading order
    inlier = np.empty(N, dtype=np.bool_)
    x, y, u, v = X1[0], X1[1], X2[0], X2[1]
    xo, yo, uo, vo = ordered[0], ordered[1], ordered[2], ordered[3]
    early = log_A < np.inf or bail_cost < np.inf
    batch_best = np.inf  # cheapest full cost of this call so far
    for m in range(M):
        f = F[m]
        if not early:  # nothing can stop a model: every point, in index order
            cost[m], count[m] = _msac_all(f, x, y, u, v, threshold, e, inlier)
            read[m] = N
            batch_best = min(batch_best, cost[m])
            continue
        c = 0.0
        k = 0
        llr = 0.0
        stop = False
        j = 0
        lo = 0
        while lo < N and not stop:
            if lo < _SINGLY:  # one point (the cheap test decides most of a bad model's)
                hi = lo + 1
                d = _distance_within(f, xo[lo], yo[lo], uo[lo], vo[lo], cap2)
                inlier[lo] = d < threshold
                e[lo] = d * d if inlier[lo] else t2
            else:  # a chunk of vectorised terms
                hi = min(N, lo + _CHUNK)
                point_costs(f, xo, yo, uo, vo, lo, hi, threshold, e, inlier)
            for jj in range(lo, hi):
                j = jj + 1
                ej = e[jj]
                per_point[order[jj]] = ej
                if inlier[jj]:
                    k += 1
                    llr += log_in
                else:
                    llr += log_out
                c += ej
                if llr > log_A:
                    rejected[m] = True
                    stop = True
                    break
                if c >= bail_cost and c > batch_best and k + (N - j) < bail_count:
                    stop = True
                    break
            lo = hi
        read[m] = j
        count[m] = k
        if stop:
            cost[m] = np.inf
        else:
            c = 0.0
            for i in range(N):  # the same summation order as msac_kernel: bit-identical cost
                c += per_point[i]
            cost[m] = c
            batch_best = min(batch_best, c)
    return cost, count, read, rejected


@numba.njit(cache=True, nogil=True, inline="always")
def to_unit_norm(G: np.ndarray) -> bool:
    """Scale G (3, 3) in place to unit Frobenius norm; False (G unchanged) if zero or not finite."""
    n = 0.0
    for i in range(3):
        for j in range(3):
            n += G[i, j] * G[i, j]
    if not (np.isfinite(n) and n > 0):
        return False
    n = np.sqrt(n)
    for i in range(3):
        for j in range(3):
            G[i, j] /= n
    return True


@numba.njit(cache=True, nogil=True)
def rank2_unit_kernel(F: np.ndarray) -> np.ndarray:
    """(3, 3) -> closest rank-2 matrix (Frobenius), scaled to unit norm.

    One-sided Jacobi: rotate the columns of F by V until they are orthogonal (F V = U S, as
    accurate as an SVD and much cheaper for 3x3), zero the shortest column and rotate back.
    """
    A = F.copy()
    V = np.eye(3)
    for _ in range(30):
        rotated = False
        for p in range(2):
            for q in range(p + 1, 3):
                alpha = A[0, p] ** 2 + A[1, p] ** 2 + A[2, p] ** 2
                beta = A[0, q] ** 2 + A[1, q] ** 2 + A[2, q] ** 2
                gamma = A[0, p] * A[0, q] + A[1, p] * A[1, q] + A[2, p] * A[2, q]
                if abs(gamma) <= 1e-15 * np.sqrt(alpha * beta) or gamma == 0.0:
                    continue
                rotated = True
                zeta = (beta - alpha) / (2.0 * gamma)
                t = (1.0 if zeta >= 0 else -1.0) / (abs(zeta) + np.sqrt(1.0 + zeta * zeta))
                c = 1.0 / np.sqrt(1.0 + t * t)
                s = c * t
                for i in range(3):
                    ap, aq = A[i, p], A[i, q]
                    A[i, p], A[i, q] = c * ap - s * aq, s * ap + c * aq
                    vp, vq = V[i, p], V[i, q]
                    V[i, p], V[i, q] = c * vp - s * vq, s * vp + c * vq
        if not rotated:
            break
    k, smallest = 0, np.inf
    for j in range(3):
        n = A[0, j] ** 2 + A[1, j] ** 2 + A[2, j] ** 2
        if n < smallest:
            k, smallest = j, n
    G = np.zeros((3, 3))  # (F V with column k zeroed) V^T
    for i in range(3):
        for j in range(3):
            for m in range(3):
                if m != k:
                    G[i, j] += A[i, m] * V[j, m]
    to_unit_norm(G)
    return G


@numba.njit(cache=True, nogil=True)
def denormalize_kernel(F_n: np.ndarray, T1: np.ndarray, T2: np.ndarray, out: np.ndarray) -> bool:
    """out (3, 3) = T2^T F_n T1 at unit Frobenius norm; False (out undefined) if not finite/zero."""
    tmp = np.zeros((3, 3))
    for i in range(3):
        for j in range(3):
            for k in range(3):
                tmp[i, j] += F_n[i, k] * T1[k, j]
    for i in range(3):
        for j in range(3):
            out[i, j] = T2[0, i] * tmp[0, j] + T2[1, i] * tmp[1, j] + T2[2, i] * tmp[2, j]
    return to_unit_norm(out)


@numba.njit(cache=True, nogil=True)
def denormalize_unit_kernel(F_n: np.ndarray, T1: np.ndarray, T2: np.ndarray) -> np.ndarray:
    """T2^T F_n T1 (3, 3) at unit Frobenius norm, largest-magnitude entry positive."""
    F = np.zeros((3, 3))
    if not denormalize_kernel(F_n, T1, T2, F):
        return F
    big = 0.0
    for i in range(3):
        for j in range(3):
            if abs(F[i, j]) > abs(big):
                big = F[i, j]
    if big < 0:
        for i in range(3):
            for j in range(3):
                F[i, j] = -F[i, j]
    return F


def symmetric_epipolar_distance_h(F: np.ndarray, X1: np.ndarray, X2: np.ndarray) -> np.ndarray:
    """:func:`symmetric_epipolar_distance` of (M, 3, 3) models on homogeneous (3, N) points.

    The hot path of RANSAC scoring (compiled): the points are prepared once per estimate.
    Returns (M, N) px, inf where an epipolar line is undefined.
    """
    return distances_kernel(
        np.ascontiguousarray(F, dtype=np.float64),
        np.ascontiguousarray(X1, dtype=np.float64),
        np.ascontiguousarray(X2, dtype=np.float64),
    )


def symmetric_epipolar_distance(F: np.ndarray, pts1: np.ndarray, pts2: np.ndarray) -> np.ndarray:
    """Symmetric epipolar distance in pixels: the mean of the two point-to-epipolar-line distances.

    d = (|x2^T F x1| / ||(F x1)_{1:2}|| + |x2^T F x1| / ||(F^T x2)_{1:2}||) / 2.

    Args:
        F: (3, 3) or (M, 3, 3) fundamental matrices with x2^T F x1 = 0.
        pts1, pts2: (N, 2) pixel coordinates in image 1 and image 2.
    Returns:
        (N,) for a single F, (M, N) for a batch; inf where an epipolar line is undefined.
    """
    F = np.asarray(F, dtype=np.float64)
    d = symmetric_epipolar_distance_h(
        F[None] if F.ndim == 2 else F, homogeneous_columns(pts1), homogeneous_columns(pts2)
    )
    return d[0] if F.ndim == 2 else d


def sampson_distance(F: np.ndarray, pts1: np.ndarray, pts2: np.ndarray) -> np.ndarray:
    """Sampson distance in pixels (first-order geometric error, square-rooted).

    d = |x2^T F x1| / sqrt((F x1)_1^2 + (F x1)_2^2 + (F^T x2)_1^2 + (F^T x2)_2^2).

    Shapes as :func:`symmetric_epipolar_distance`.
    """
    F = np.asarray(F, dtype=np.float64)
    Fs = F[None] if F.ndim == 2 else F
    r, l2, l1 = _epipolar_terms(Fs, homogeneous_columns(pts1), homogeneous_columns(pts2))
    den = l2[:, 0] ** 2 + l2[:, 1] ** 2 + l1[:, 0] ** 2 + l1[:, 1] ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        d = np.abs(r) / np.sqrt(den)
    d = np.where(np.isfinite(d), d, np.inf)
    return d[0] if np.asarray(F).ndim == 2 else d


def camera_center(P: np.ndarray) -> np.ndarray:
    """Homogeneous centre (4,) of a finite or infinite 3x4 camera: the null vector of P."""
    _, _, Vt = np.linalg.svd(np.asarray(P, dtype=np.float64))
    return Vt[-1]


def fundamental_from_cameras(P1: np.ndarray, P2: np.ndarray) -> np.ndarray:
    """F with x2^T F x1 = 0 from two 3x4 cameras: F = [e2]_x P2 P1^+, e2 = P2 C1.

    Returned with unit Frobenius norm and its largest-magnitude entry positive.
    """
    P1 = np.asarray(P1, dtype=np.float64)
    P2 = np.asarray(P2, dtype=np.float64)
    e2 = P2 @ camera_center(P1)
    F = skew(e2) @ P2 @ np.linalg.pinv(P1)
    return normalize_fundamental(F)


@numba.njit(cache=True, nogil=True)
def hartley_kernel(pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N, 2) pixels (N >= 1) -> (Hartley's T (3, 3), the points normalised by T (N, 2))."""
    n = pts.shape[0]
    cu, cv = pts[:, 0].mean(), pts[:, 1].mean()
    d = 0.0
    for i in range(n):
        d += np.hypot(pts[i, 0] - cu, pts[i, 1] - cv)
    d /= n
    s = np.sqrt(2.0) / d if d > 0 else 1.0
    T = np.array([[s, 0.0, -s * cu], [0.0, s, -s * cv], [0.0, 0.0, 1.0]])
    x = np.empty((n, 2))
    for i in range(n):
        x[i, 0] = s * (pts[i, 0] - cu)
        x[i, 1] = s * (pts[i, 1] - cv)
    return T, x


def normalization_transform(pts: np.ndarray) -> np.ndarray:
    """Hartley's similarity T (3, 3): centroid to origin, mean distance to the origin sqrt(2).

    Args:
        pts: (N, 2) pixel coordinates, N >= 1.
    """
    return hartley_kernel(np.ascontiguousarray(pts, dtype=np.float64))[0]


def apply_transform(T: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Apply an affine 3x3 transform to (..., 2) points."""
    return pts @ T[:2, :2].T + T[:2, 2]


def denormalize(F_n: np.ndarray, T1: np.ndarray, T2: np.ndarray) -> np.ndarray:
    """F in pixels from F in normalised coordinates: F = T2^T F_n T1, batched over (..., 3, 3)."""
    return T2.T @ F_n @ T1
