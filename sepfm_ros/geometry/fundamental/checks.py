"""Input checks: malformed matches and sizes (``ValueError``), point sets that fix no F (all on
one line, no motion), and final inliers in a band around one line (paper Sec. 3: a line pair
fixes only 3 of F's 7 degrees of freedom)."""

from __future__ import annotations

from typing import Any

import numba
import numpy as np

__all__ = ["input_degeneracy", "line_band_status", "validate_points", "validate_size"]


def validate_points(pts1: Any, pts2: Any, min_points: int) -> tuple[np.ndarray, np.ndarray]:
    p1 = np.ascontiguousarray(pts1, dtype=np.float64)
    p2 = np.ascontiguousarray(pts2, dtype=np.float64)
    for name, p in (("pts1", p1), ("pts2", p2)):
        if p.ndim != 2 or p.shape[1] != 2:
            raise ValueError(f"{name} must have shape (N, 2), got {p.shape}")
    if p1.shape != p2.shape:
        raise ValueError(f"pts1 and pts2 must have the same shape, got {p1.shape} and {p2.shape}")
    if p1.shape[0] < min_points:
        raise ValueError(f"need at least {min_points} correspondences, got {p1.shape[0]}")
    n_bad, first_bad = _count_nonfinite(p1, p2)
    if n_bad:
        raise ValueError(f"{n_bad} correspondences contain NaN or inf (first at index {first_bad})")
    n_same, i, j = _count_duplicates(p1, p2)
    if n_same:
        raise ValueError(
            f"{n_same} duplicate correspondences (e.g. the matches at indices {i} and "
            f"{j} are identical); remove duplicates first"
        )
    return p1, p2


def validate_size(size: Any, name: str) -> tuple[float, float]:
    if size is None:
        raise ValueError(f"{name} is required: (width, height) in pixels")
    try:
        w, h = (float(v) for v in size)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be (width, height), got {size!r}") from exc
    if not (np.isfinite(w) and np.isfinite(h) and w > 0 and h > 0):
        raise ValueError(f"{name} must be positive and finite, got {size!r}")
    return w, h


@numba.njit(cache=True, nogil=True)
def _count_nonfinite(p1: np.ndarray, p2: np.ndarray) -> tuple[int, int]:
    """(number of rows of (N, 2) p1 / p2 with a NaN or inf, index of the first such row or -1)."""
    count, first = 0, -1
    for i in range(p1.shape[0]):
        if not (
            np.isfinite(p1[i, 0])
            and np.isfinite(p1[i, 1])
            and np.isfinite(p2[i, 0])
            and np.isfinite(p2[i, 1])
        ):
            count += 1
            if first < 0:
                first = i
    return count, first


@numba.njit(cache=True, nogil=True)
def _count_duplicates(p1: np.ndarray, p2: np.ndarray) -> tuple[int, int, int]:
    """(rows equal to an earlier row, and the first such pair (i < j) or (-1, -1)).

    Rows are (p1[i], p2[i]); sorted by p1's u, equal rows sit in runs of equal u.
    """
    n = p1.shape[0]
    order = np.argsort(p1[:, 0])
    count, fi, fj = 0, -1, -1
    start = 0
    while start < n:
        end = start + 1
        while end < n and p1[order[end], 0] == p1[order[start], 0]:
            end += 1
        for a in range(start + 1, end):  # is row order[a] equal to an earlier one in the run?
            ia = order[a]
            for b in range(start, a):
                ib = order[b]
                if p1[ia, 1] == p1[ib, 1] and p2[ia, 0] == p2[ib, 0] and p2[ia, 1] == p2[ib, 1]:
                    count += 1
                    if fi < 0:
                        fi, fj = min(ia, ib), max(ia, ib)
                    break
        start = end
    return count, fi, fj


@numba.njit(cache=True, nogil=True)
def _principal_scatter(p: np.ndarray) -> tuple[float, float]:
    """(small, large) eigenvalues of the 2x2 scatter matrix (sum of outer products about the
    mean, px^2) of (N, 2) points."""
    n = p.shape[0]
    mu, mv = p[:, 0].mean(), p[:, 1].mean()
    a = b = c = 0.0
    for i in range(n):
        du, dv = p[i, 0] - mu, p[i, 1] - mv
        a += du * du
        b += du * dv
        c += dv * dv
    big = 0.5 * (a + c) + np.sqrt(0.25 * (a - c) ** 2 + b * b)
    if big <= 0:
        return 0.0, 0.0
    return max(0.0, (a * c - b * b) / big), big  # det / big = the small eigenvalue


@numba.njit(cache=True, nogil=True)
def _spread_ratio(p: np.ndarray) -> float:
    """Smallest / largest eigenvalue of the 2x2 scatter matrix of (N, 2) points (0: collinear)."""
    small, big = _principal_scatter(p)
    return small / big if big > 0 else 0.0


@numba.njit(cache=True, nogil=True)
def _across_std(p: np.ndarray) -> float:
    """Standard deviation (px) of (N >= 2, 2) points across their principal axis."""
    small, _ = _principal_scatter(p)
    return np.sqrt(small / (p.shape[0] - 1))


@numba.njit(cache=True, nogil=True)
def _median_motion(p1: np.ndarray, p2: np.ndarray) -> float:
    """Median over correspondences of ||p2 - p1|| (px)."""
    d = np.empty(p1.shape[0])
    for i in range(p1.shape[0]):
        d[i] = np.hypot(p2[i, 0] - p1[i, 0], p2[i, 1] - p1[i, 1])
    return np.median(d)


def input_degeneracy(p1: np.ndarray, p2: np.ndarray, threshold: float) -> str | None:
    """A reason why no F can be determined from these points, or None."""
    for name, p in (("image 1", p1), ("image 2", p2)):
        if _spread_ratio(p) <= 1e-12:
            return f"degenerate: all points on one line in {name}"
    if _median_motion(p1, p2) < 0.1 * threshold:
        return "degenerate: no motion (points do not move between the images)"
    return None


def line_band_status(q1: np.ndarray, q2: np.ndarray, threshold: float) -> str | None:
    """A reason when the inliers (K, 2) of either image lie in a band around one line.

    Matches within a couple of pixels of one image line fix only the line pair's share of F
    (3 of its 7 degrees of freedom, paper Sec. 3); the rest is fitted to noise. The band is the
    standard deviation across the points' principal axis, compared with 2 x ``threshold``.
    """
    for name, q in (("image 1", q1), ("image 2", q2)):
        if len(q) < 2:
            continue
        across = _across_std(np.ascontiguousarray(q))
        if across < 2.0 * threshold:
            return (
                f"degenerate: the {len(q)} inliers lie along one line in {name} "
                f"({across:.1f} px across it)"
            )
    return None
