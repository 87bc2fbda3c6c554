"""Least-squares refits on inliers and Sampson-error refinement (IRLS), rank 2 enforced.

Used by local optimisation inside RANSAC (LO-RANSAC) and for the final model. All fits work on
the normalised coordinates of :class:`Correspondences` (computed once); a refit costs one weighted
9x9 Gram matrix and one eigen-decomposition, and the whole iterative refit is one compiled call.
"""

from __future__ import annotations

import numba
import numpy as np

from sepfm_ros.geometry.epipolar import (
    denormalize_unit_kernel,
    distances_within_kernel,
    rank2_unit_kernel,
)
from sepfm_ros.geometry.fundamental.correspondences import Correspondences
from sepfm_ros.geometry.robust.lmeds import lmeds_final_inliers
from sepfm_ros.geometry.solvers.cholesky import cholesky_lower, cholesky_solve
from sepfm_ros.geometry.solvers.design import column_gram, design_row

#: Inlier-threshold factors of :func:`iterative_refit`, loosest first (LO-RANSAC's iterative step).
REFIT_FACTORS = (3.0, 1.5, 1.0, 1.0)


@numba.njit(cache=True, nogil=True)
def _weighted_design(
    x1: np.ndarray, x2: np.ndarray, idx: np.ndarray, w: np.ndarray, R: np.ndarray
) -> None:
    """Write w_k r_k into the columns of R (9, K): the design rows r (:func:`design_row`) of
    the matches idx (K,), weighted by w (K,); x1, x2: (N, 2) normalised coordinates. Their
    Gram matrix (:func:`column_gram`) is sum_k w_k^2 r_k r_k^T."""
    for k in range(idx.shape[0]):
        i, wk = idx[k], w[k]
        r = R[:, k]
        # w_k kron([u, v, 1], [x, y, 1]) = kron([w_k u, w_k v, w_k], [x, y, 1])
        design_row(x1[i, 0], x1[i, 1], wk * x2[i, 0], wk * x2[i, 1], r)
        # (entry by entry: a slice update ``r[6:] *= wk`` allocates a temporary per row)
        r[6] *= wk
        r[7] *= wk
        r[8] *= wk


#: Inverse iteration of :func:`smallest_eigenvector`: most steps, and the agreement of two
#: consecutive unit iterates (largest entry difference) that ends it.
INVERSE_ITERATIONS = 16
INVERSE_TOLERANCE = 1e-13


@numba.njit(cache=True, nogil=True)
def smallest_eigenvector(G: np.ndarray, start: np.ndarray) -> np.ndarray:
    """(9,) unit eigenvector of the smallest eigenvalue of a symmetric PSD G (9, 9).

    Inverse iteration from ``start`` (9,), e.g. the model being refitted, with one Cholesky
    factorisation of G + 1e-14 tr(G) I (the shift keeps an exactly singular G factorisable and
    leaves the eigenvectors as they are): each step solves two triangular 9x9 systems, and a
    start near the answer converges in 3-5 steps, against one LAPACK ``eigh`` of the whole
    spectrum at several times the cost. Falls back to ``eigh`` when the factorisation fails,
    ``start`` is zero or the iterates do not settle within INVERSE_ITERATIONS steps (two
    nearly equal smallest eigenvalues).
    """
    n = 9
    norm = 0.0
    for i in range(n):
        norm += start[i] * start[i]
    trace = 0.0
    for i in range(n):
        trace += G[i, i]
    L = np.zeros((n, n))
    ok = norm > 0.0 and np.isfinite(norm) and trace > 0.0 and np.isfinite(trace)
    ok = ok and cholesky_lower(G, 1e-14 * trace, L)
    if ok:
        v = start / np.sqrt(norm)
        y = np.empty(n)
        w = np.empty(n)
        for _ in range(INVERSE_ITERATIONS):
            cholesky_solve(L, v, y, w)  # w = (G + 1e-14 tr(G) I)^-1 v
            nw, dot = 0.0, 0.0
            for i in range(n):
                nw += w[i] * w[i]
                dot += w[i] * v[i]
            if not (nw > 0.0 and np.isfinite(nw)):
                break
            scale = (1.0 if dot >= 0.0 else -1.0) / np.sqrt(nw)
            change = 0.0
            for i in range(n):
                w[i] *= scale
                change = max(change, abs(w[i] - v[i]))
                v[i] = w[i]
            if change < INVERSE_TOLERANCE:
                return v
    _, vecs = np.linalg.eigh(G)
    return vecs[:, 0].copy()


@numba.njit(cache=True, nogil=True)
def _solve_gram(G: np.ndarray, start: np.ndarray) -> np.ndarray:
    """Rank-2 unit-norm F_n (3, 3): the eigenvector of the smallest eigenvalue of G (9, 9),
    by inverse iteration from ``start`` (9,) (:func:`smallest_eigenvector`)."""
    vec = smallest_eigenvector(G, start)
    F = np.empty((3, 3))
    for i in range(9):
        F[i // 3, i % 3] = vec[i]
    return rank2_unit_kernel(F)


@numba.njit(cache=True, nogil=True)
def normalized_model(F: np.ndarray, T1: np.ndarray, T2: np.ndarray) -> np.ndarray:
    """(9,) F_n = T2^-T F T1^-1 of a pixel F (3, 3), row-major (the inverse of
    ``denormalize``): the model in the normalised coordinates the refits solve in."""
    return (np.linalg.inv(T2).T @ F @ np.linalg.inv(T1)).ravel().copy()


@numba.njit(cache=True, nogil=True)
def _sampson_weights(
    F_n: np.ndarray, x1: np.ndarray, x2: np.ndarray, idx: np.ndarray
) -> np.ndarray:
    """(K,) 1 / ||grad(x2^T F x1)|| (the Sampson denominator) of rows idx, scaled to max 1."""
    K = idx.shape[0]
    g = np.empty(K)
    for k in range(K):
        i = idx[k]
        x, y, u, v = x1[i, 0], x1[i, 1], x2[i, 0], x2[i, 1]
        a2 = F_n[0, 0] * x + F_n[0, 1] * y + F_n[0, 2]
        b2 = F_n[1, 0] * x + F_n[1, 1] * y + F_n[1, 2]
        a1 = F_n[0, 0] * u + F_n[1, 0] * v + F_n[2, 0]
        b1 = F_n[0, 1] * u + F_n[1, 1] * v + F_n[2, 1]
        g[k] = np.sqrt(a2 * a2 + b2 * b2 + a1 * a1 + b1 * b1)
    floor = 1e-12 * max(g.max(), 1e-300)
    w = 1.0 / np.maximum(g, floor)
    return w / w.max()


@numba.njit(cache=True, nogil=True)
def refit_kernel(
    x1: np.ndarray,
    x2: np.ndarray,
    idx: np.ndarray,
    irls_iterations: int,
    T1: np.ndarray,
    T2: np.ndarray,
    start: np.ndarray,
) -> np.ndarray:
    """Normalised eight-point least squares on rows idx (+ Sampson IRLS); F in px, unit norm.

    x1, x2: (N, 2) normalised coordinates (``Correspondences.x1`` / ``x2``); idx: (K,) int
    rows to fit; T1, T2: (3, 3) their normalising transforms. Compiled, for callers that fit
    many index sets in one kernel (:func:`iterative_refit`, inner sampling).

    start: (9,) normalised model the first solve starts from (each IRLS solve starts from the
    previous one); zeros for none (a full eigen-decomposition, see
    :func:`smallest_eigenvector`).
    """
    K = idx.shape[0]
    R = np.empty((9, K))
    _weighted_design(x1, x2, idx, np.ones(K), R)
    F_n = _solve_gram(column_gram(R, K), start)
    for _ in range(irls_iterations):
        _weighted_design(x1, x2, idx, _sampson_weights(F_n, x1, x2, idx), R)
        F_n = _solve_gram(column_gram(R, K), F_n.ravel().copy())
    return denormalize_unit_kernel(F_n, T1, T2)


@numba.njit(cache=True, nogil=True)
def _iterative_refit_kernel(
    F: np.ndarray,
    X1: np.ndarray,
    X2: np.ndarray,
    x1: np.ndarray,
    x2: np.ndarray,
    T1: np.ndarray,
    T2: np.ndarray,
    threshold: float,
    factors: np.ndarray,
    irls_iterations: int,
) -> np.ndarray:
    """See :func:`iterative_refit`; returns (K, 3, 3) fitted models, K <= len(factors)."""
    t2 = threshold * threshold
    # distances beyond every factor's threshold (and the cost's) only need to be known as such
    cap = max(factors.max(), 1.0) * threshold
    start = normalized_model(F, T1, T2)  # each refit starts from the current model
    d = distances_within_kernel(F.reshape(1, 3, 3), X1, X2, cap)[0]
    best_cost = np.minimum(d * d, t2).sum()
    out = np.empty((factors.shape[0], 3, 3))
    n_out = 0
    previous = np.zeros(d.shape[0], dtype=np.bool_)
    have_previous = False
    for j in range(factors.shape[0]):
        inl = d < factors[j] * threshold
        if inl.sum() < 8:
            continue
        if have_previous and np.array_equal(inl, previous):
            if j == factors.shape[0] - 1:
                break
            continue
        previous = inl
        have_previous = True
        G = refit_kernel(x1, x2, np.flatnonzero(inl), irls_iterations, T1, T2, start)
        dG = distances_within_kernel(G.reshape(1, 3, 3), X1, X2, cap)[0]
        c = np.minimum(dG * dG, t2).sum()
        for a in range(3):
            for b in range(3):
                out[n_out, a, b] = G[a, b]
        n_out += 1
        if c < best_cost:  # continue from the better model
            best_cost = c
            d = dG
            start = normalized_model(G, T1, T2)
    return out[:n_out]


def refit(data: Correspondences, inliers: np.ndarray, irls_iterations: int = 0) -> np.ndarray:
    """Normalised eight-point least squares on the inliers, then Sampson IRLS iterations.

    Args:
        data: the matches. inliers: (N,) bool with at least 8 True.
        irls_iterations: reweighted solves that reduce the Sampson error (0: plain least squares).
    Returns:
        (3, 3) rank-2 F in pixels, unit Frobenius norm.
    """
    idx = np.flatnonzero(inliers)
    return refit_kernel(data.x1, data.x2, idx, int(irls_iterations), data.T1, data.T2, np.zeros(9))


def fit_least_squares(pts1: np.ndarray, pts2: np.ndarray, irls_iterations: int = 0) -> np.ndarray:
    """F (3, 3) from K >= 8 pixel correspondences (K, 2): normalised eight-point (+ IRLS)."""
    data = Correspondences.from_pixels(pts1, pts2)
    return refit(data, np.ones(len(data), dtype=bool), irls_iterations)


def iterative_refit(
    F: np.ndarray,
    data: Correspondences,
    threshold: float,
    factors: tuple[float, ...] = REFIT_FACTORS,
    irls_iterations: int = 2,
) -> np.ndarray:
    """Refit F on its inliers under a shrinking threshold (LO-RANSAC's iterative least squares).

    Each step takes the inliers of the current model at ``factor * threshold`` px (symmetric
    epipolar distance) and refits them (:func:`refit`); a step's model becomes current only if
    its truncated-quadratic (MSAC) cost at ``threshold`` is lower. From a rough model (e.g. one
    whose minimal sample was badly conditioned) this reaches the best model of its basin.

    Args:
        F: (3, 3) start model in pixels. data: all matches.
    Returns:
        (K, 3, 3) every model fitted on the way (each was scored against all matches; the
        caller picks the best by its own scoring); K = 0 when no step had 8 inliers.
    """
    return _iterative_refit_kernel(
        np.ascontiguousarray(F, dtype=np.float64), data.X1, data.X2, data.x1, data.x2,
        data.T1, data.T2, float(threshold), np.asarray(factors, dtype=np.float64),
        int(irls_iterations),
    )  # fmt: skip


def lmeds_refit(
    F: np.ndarray,
    data: Correspondences,
    model_points: int,
    steps: int = 2,
    irls_iterations: int = 0,
) -> np.ndarray:
    """Least-median refits: refit F on its robust inliers, as long as the median improves.

    Each step takes the robust inliers of the current model (within 2.5 sigma of it, sigma its
    reweighted LMedS scale, :func:`sepfm_ros.geometry.robust.lmeds.lmeds_final_inliers`
    with p = ``model_points``) and refits them (:func:`refit`); the refit becomes current only
    if its median squared symmetric epipolar distance is lower, otherwise the refits stop.

    Returns:
        (K, 3, 3) every model fitted (K <= steps; 0 when the robust inliers are fewer than 8).
    """
    out = []
    d = data.distances(np.ascontiguousarray(F, dtype=np.float64))
    inl, _, med = lmeds_final_inliers(d, model_points)
    for _ in range(steps):
        if np.count_nonzero(inl) < 8:
            break
        G = refit(data, inl, irls_iterations)
        out.append(G)
        dG = data.distances(G)
        inl_g, _, med_g = lmeds_final_inliers(dG, model_points)
        if not med_g < med:
            break
        inl, med = inl_g, med_g
    return np.stack(out) if out else np.zeros((0, 3, 3))
