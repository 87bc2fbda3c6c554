"""Samplers of the robust loop: uniform k-subsets of a pool (Floyd) and PROSAC over a pool ordered
best first (Chum & Matas 2005)."""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["ProsacSampler", "draw_samples", "prosac_schedule"]


@numba.njit(cache=True, nogil=True)
def _floyd_samples(u: np.ndarray, P: int) -> np.ndarray:
    """(b, k) distinct indices in [0, P) per row from (b, k) uniforms in [0, 1) (Floyd's method).

    Row i is a uniformly random k-subset of range(P): for j = P - k .. P - 1 take t uniform in
    [0, j]; keep t unless already taken, else keep j.
    """
    b, k = u.shape
    out = np.empty((b, k), dtype=np.int64)
    for i in range(b):
        for m in range(k):
            j = P - k + m
            t = min(int(u[i, m] * (j + 1)), j)
            for q in range(m):
                if out[i, q] == t:
                    t = j
                    break
            out[i, m] = t
    return out


def draw_samples(rng: np.random.Generator, pool: np.ndarray, k: int, b: int) -> np.ndarray:
    """(b, k) samples of k distinct entries of ``pool`` each, uniformly at random."""
    P = pool.shape[0]
    if P < k:
        raise ValueError(f"cannot draw {k} distinct points from a pool of {P}")
    return pool[_floyd_samples(rng.random((b, k)), P)]


def prosac_schedule(P: int, k: int, growth: int) -> np.ndarray:
    """PROSAC's T'_n for n = k .. P (Chum & Matas 2005), as an int64 array indexed n - k.

    T_n = growth * C(n, k) / C(P, k) is the expected number, among ``growth`` uniform samples
    of the whole pool, of samples drawn from the top n; T'_k = 1 and T'_{n+1} = T'_n +
    ceil(T_{n+1} - T_n), so every n gets at least one sample. Sample t (1-based) with
    T'_{n-1} < t <= T'_n is the n-th entry plus k - 1 drawn from the top n - 1.
    """
    if P < k:
        raise ValueError(f"cannot draw {k} distinct points from a pool of {P}")
    return _prosac_schedule_kernel(P, k, float(growth))


@numba.njit(cache=True, nogil=True)
def _prosac_schedule_kernel(P: int, k: int, growth: float) -> np.ndarray:
    """:func:`prosac_schedule` for P >= k (compiled: it runs once per arm of every estimate)."""
    T = growth
    for i in range(k):
        T *= (k - i) / (P - i)  # T_k
    out = np.empty(P - k + 1, dtype=np.int64)
    out[0] = 1
    for n in range(k, P):
        T_next = T * (n + 1) / (n + 1 - k)
        out[n - k + 1] = out[n - k] + max(1, int(np.ceil(T_next - T)))
        T = T_next
    return out


@numba.njit(cache=True, nogil=True)
def _prosac_samples(u: np.ndarray, t0: int, P: int, schedule: np.ndarray) -> np.ndarray:
    """(b, k) PROSAC samples t0 + 1 .. t0 + b (positions in the quality-ordered pool) from
    (b, k) uniforms; uniform over range(P) (Floyd) once t exceeds the schedule's last T'_P."""
    b, k = u.shape
    out = np.empty((b, k), dtype=np.int64)
    n = k
    last = schedule.shape[0] - 1
    for i in range(b):
        t = t0 + i + 1
        while n - k < last and schedule[n - k] < t:
            n += 1
        if schedule[n - k] < t:  # past the schedule: plain RANSAC over the whole pool
            top, forced = P, -1
        else:
            top, forced = n - 1, n - 1
        first = 0
        if forced >= 0:
            out[i, 0] = forced
            first = 1
        kk = k - first
        for m in range(kk):  # Floyd: a uniform kk-subset of range(top)
            j = top - kk + m
            v = min(int(u[i, m] * (j + 1)), j)
            for q in range(first, first + m):
                if out[i, q] == v:
                    v = j
                    break
            out[i, first + m] = v
    return out


class ProsacSampler:
    """PROSAC over a pool ordered best first: deterministic given the generator's state.

    Args:
        pool: (P,) indices, best first.
        k: sample size.
        growth: T_N, the number of samples after which PROSAC has grown to the whole pool and
            sampling is uniform (plain RANSAC).
    """

    def __init__(self, pool: np.ndarray, k: int, growth: int) -> None:
        self.pool, self.k = pool, k
        self.schedule = prosac_schedule(len(pool), k, growth)
        self.t = 0  #: samples drawn so far

    def top(self, t: int) -> int:
        """Size of the top of the pool that sample t (1-based) is drawn from."""
        n = int(np.searchsorted(self.schedule, t)) + self.k
        return min(n, len(self.pool))

    def draw(self, rng: np.random.Generator, b: int) -> np.ndarray:
        """(b, k) next samples (entries of the pool)."""
        idx = _prosac_samples(rng.random((b, self.k)), self.t, len(self.pool), self.schedule)
        self.t += b
        return self.pool[idx]
