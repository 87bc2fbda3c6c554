"""Repetitive structure on a line pair: is the support of H_e a periodic 1D point set?

Points equally spaced along a 3D line (a row of windows, a chessboard row) image to a projective
arithmetic progression: in a chart where the line's vanishing point is at infinity they are
0, 1, 2, ...; the shift by one period is then x -> x + 1, seen in the image as a *parabolic* 1D
homography G (one fixed point, the vanishing point). Four consecutive points a, b, c, d of such a
progression have the cross ratio

    cr(a, b; c, d) = ((c - a) (d - b)) / ((c - b) (d - a)) = 4 / 3,

and, conversely, cr = 4/3 is exactly when the homography G with a -> b, b -> c, c -> d is
parabolic. Matches along such a row are often off by one period; they still lie on an image line
pair and follow a 1D homography exactly (H_e G is one too), so stage 1 accepts them and the F
through a triple of them is wrong. A line pair whose H_e support admits a shift G mapping a large
share of its points onto other points of the support is therefore ambiguous: its H_e may be off
by a period.

:func:`periodic_shift` tests that, projectively invariantly up to the pixel tolerance: shift
hypotheses G from quadruples of neighbouring points (every ``stride``-th point of the sorted
parameters, so interleaved progressions such as the left and right corners of a row of windows
are found too) whose cross ratio is near 4/3, each scored by the number of points it maps within
``tol`` px of another point of the set (and at least ``tol`` px away from itself); the best
hypothesis is refined once by least squares on its hits and re-scored.
"""

from __future__ import annotations

import math

import numba
import numpy as np

#: cross ratio of four consecutive points of a projective arithmetic progression
PROGRESSION_CROSS_RATIO = 4.0 / 3.0
#: the refits of :func:`periodic_progression` use the points within this fraction of the local
#: period of their node
ASSIGN_REL = 0.3
#: nodes a refit of :func:`periodic_progression` reaches beyond those of the previous one
GROW = 3.0


@numba.njit(cache=True, nogil=True)
def _fit_progression(t: np.ndarray, n: np.ndarray, w: np.ndarray, out: np.ndarray) -> bool:
    """Least-squares progression t(n) = (a n + b) / (c n + 1) through the points t[k] at integer
    indices n[k] where w[k] (the linear equations a n + b - c n t = t); out (3,) = (a, b, c).
    False when the 3x3 normal equations are singular or fewer than 3 points are given."""
    M = np.zeros((3, 3))
    v = np.zeros(3)
    r = np.empty(3)
    cnt = 0
    for k in range(len(t)):
        if not w[k]:
            continue
        cnt += 1
        r[0], r[1], r[2] = n[k], 1.0, -n[k] * t[k]
        for i in range(3):
            v[i] += r[i] * t[k]
            for j in range(3):
                M[i, j] += r[i] * r[j]
    if cnt < 3:
        return False
    det = (
        M[0, 0] * (M[1, 1] * M[2, 2] - M[1, 2] * M[2, 1])
        - M[0, 1] * (M[1, 0] * M[2, 2] - M[1, 2] * M[2, 0])
        + M[0, 2] * (M[1, 0] * M[2, 1] - M[1, 1] * M[2, 0])
    )
    if not abs(det) > 1e-300:
        return False
    for col in range(3):  # Cramer's rule
        A = M.copy()
        for i in range(3):
            A[i, col] = v[i]
        out[col] = (
            A[0, 0] * (A[1, 1] * A[2, 2] - A[1, 2] * A[2, 1])
            - A[0, 1] * (A[1, 0] * A[2, 2] - A[1, 2] * A[2, 0])
            + A[0, 2] * (A[1, 0] * A[2, 1] - A[1, 1] * A[2, 0])
        ) / det
    return True


@numba.njit(cache=True, nogil=True)
def _progression_hits(
    abc: np.ndarray, t: np.ndarray, length: float, tol: float, rel: float, n: np.ndarray
) -> int:
    """Points of t (K,) on the progression t(n) = (a n + b) / (c n + 1) at an integer n.

    A point is on it when it lies within min(``tol`` px, ``rel`` times the local period
    |dt/dn|) of its nearest node (the error relative to the period is projectively invariant to
    first order, and it makes the chance that a random point hits a node 2 ``rel`` whatever the
    period); nodes beyond the vanishing point (c n + 1 of the other sign than at n = 0) do not
    count. ``length`` converts t to px. n (K,) receives each point's node (any value if no hit).
    """
    a, b, c = abc[0], abc[1], abc[2]
    det = a - b * c  # dt/dn = det / (c n + 1)^2
    hits = 0
    for k in range(len(t)):
        den = a - c * t[k]
        if den == 0.0:
            n[k] = 0.0
            continue
        nk = np.floor((t[k] - b) / den + 0.5)
        n[k] = nk
        q = c * nk + 1.0
        if not q > 0.0:
            continue
        err = abs((a * nk + b) / q - t[k]) * length
        if err < min(tol, rel * abs(det) / (q * q) * length):
            hits += 1
    return hits


@numba.njit(cache=True, nogil=True)
def periodic_progression(
    t: np.ndarray,
    length: float,
    tol: float,
    rel: float,
    cr_tol: float,
    max_stride: int,
    refits: int,
) -> tuple[int, np.ndarray]:
    """The projective arithmetic progression through the most points of a 1D point set.

    Hypotheses: quadruples t[i], t[i + s], t[i + 2 s], t[i + 3 s] (s = 1 .. ``max_stride``) of
    the sorted parameters whose cross ratio is within ``cr_tol`` of 4/3, taken as nodes
    0, 1, 2, 3; each is scored by :func:`_progression_hits`, and the best is refitted on its
    points near its nodes, growing from the seed's nodes (at most ``refits`` times), the
    best-scoring progression kept.

    Args:
        t: (K,) sorted line parameters of the points (point = c1 + t (c2 - c1)).
        length: |c2 - c1| in px, so that ``length * dt`` is px along the line.
        tol: px; rel: fraction of the local period (see :func:`_progression_hits`).
        cr_tol: largest |cr - 4/3| of a seeding quadruple. max_stride: >= 1. refits: >= 0.
    Returns:
        (points on the best progression, its (a, b, c) of t(n) = (a n + b) / (c n + 1)); hits 0
        when no quadruple qualifies.
    """
    K = len(t)
    best_abc = np.zeros(3)
    best = 0
    abc = np.empty(3)
    n = np.empty(K)
    w = np.zeros(K, dtype=np.bool_)
    q4 = np.empty(4)
    n4 = np.array([0.0, 1.0, 2.0, 3.0])
    w4 = np.ones(4, dtype=np.bool_)
    for s in range(1, max_stride + 1):
        for i in range(K - 3 * s):
            ta, tb, tc, td = t[i], t[i + s], t[i + 2 * s], t[i + 3 * s]
            den = (tc - tb) * (td - ta)
            if den == 0.0:
                continue
            cr = (tc - ta) * (td - tb) / den
            if abs(cr - PROGRESSION_CROSS_RATIO) > cr_tol:
                continue
            q4[0], q4[1], q4[2], q4[3] = ta, tb, tc, td
            if not _fit_progression(q4, n4, w4, abc):
                continue
            hits = _progression_hits(abc, t, length, tol, rel, n)
            if hits > best:
                best = hits
                best_abc[:] = abc
            if best == K:
                break
    # region growing: each refit uses the points within ``ASSIGN_REL`` of a period of their
    # node whose node lies at most ``GROW`` nodes beyond those of the last refit (a progression
    # seeded on four noisy points drifts off the far nodes, so it is extended a few nodes at a
    # time); the best-scoring progression is kept
    abc[:] = best_abc
    lo_n, hi_n = 0.0, 3.0
    for _ in range(refits):
        if best == K:
            break
        _progression_hits(abc, t, length, tol, rel, n)
        a, b, c = abc[0], abc[1], abc[2]
        new_lo, new_hi = np.inf, -np.inf
        for k in range(K):
            q = c * n[k] + 1.0
            w[k] = (
                q > 0.0
                and lo_n - GROW <= n[k] <= hi_n + GROW
                and abs((a * n[k] + b) / q - t[k]) < ASSIGN_REL * abs(a - b * c) / (q * q)
            )
            if w[k]:
                new_lo, new_hi = min(new_lo, n[k]), max(new_hi, n[k])
        if not _fit_progression(t, n, w, abc):
            break
        hits = _progression_hits(abc, t, length, tol, rel, n)
        if hits > best:
            best = hits
            best_abc[:] = abc
        if new_lo == lo_n and new_hi == hi_n:
            break
        lo_n, hi_n = new_lo, new_hi
    return best, best_abc


def is_periodic(
    t: np.ndarray,
    length: float,
    tol: float = 1.0,
    rel: float = 0.15,
    min_share: float = 0.8,
    min_points: int = 8,
    cr_tol: float = 0.15,
    max_stride: int = 2,
    refits: int = 10,
) -> bool:
    """True when at least ``min_share`` of the K >= ``min_points`` points lie on one projective
    arithmetic progression (:func:`periodic_progression`).

    Args:
        t: (K,) line parameters (any order). length: px per unit of t. tol: px. rel: fraction of
            the local period. cr_tol, max_stride, refits: see :func:`periodic_progression`.
    """
    t = np.sort(np.ascontiguousarray(t, dtype=np.float64))
    if len(t) < max(4, min_points):
        return False
    hits, _ = periodic_progression(
        t, float(length), float(tol), float(rel), float(cr_tol), int(max_stride), int(refits)
    )
    return hits >= math.ceil(min_share * len(t))
