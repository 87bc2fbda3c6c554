"""The epipolar design row shared by the seven- and eight-point solvers and the refits."""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, inline="always")
def design_row(x: float, y: float, u: float, v: float, r: np.ndarray) -> None:
    """Write into r (9,) the row of x2^T F x1 = 0 in vec(F) (row-major) for (x, y) <-> (u, v).

    r = kron([u, v, 1], [x, y, 1]).
    """
    r[0], r[1], r[2] = u * x, u * y, u
    r[3], r[4], r[5] = v * x, v * y, v
    r[6], r[7], r[8] = x, y, 1.0


@numba.njit(cache=True, inline="always")
def add_outer(G: np.ndarray, r: np.ndarray, weight: float) -> None:
    """G (9, 9) upper triangle += weight r r^T (symmetrise with :func:`symmetrize` at the end)."""
    for p in range(9):
        rp = r[p] * weight
        for q in range(p, 9):
            G[p, q] += rp * r[q]


@numba.njit(cache=True, inline="always")
def symmetrize(G: np.ndarray) -> None:
    """Copy the upper triangle of G (9, 9) to the lower."""
    for p in range(9):
        for q in range(p):
            G[p, q] = G[q, p]
