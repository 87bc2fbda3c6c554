"""Early rejection of minimal-sample models: Wald's SPRT (Matas & Chum 2008) and the exact
bail-out, as state shared by the arms of one run."""

from __future__ import annotations

import math
from functools import lru_cache

import numba
import numpy as np

from sepfm_ros.geometry.robust.options import SamplingOptions

__all__ = ["Sprt", "sprt_logs", "sprt_threshold"]


@numba.njit(cache=True, nogil=True)
def sprt_threshold(
    epsilon: float, delta: float, model_time: float, models_per_sample: float
) -> float:
    """Wald's A for SPRT (Matas & Chum 2008, eq. 11): the fixed point of
    A = t_M C / m_S + 1 + ln A with C = (1 - d) ln((1 - d) / (1 - e)) + d ln(d / e).

    Compiled, and shared by :class:`Sprt` and the compiled loop of
    :mod:`~sepfm_ros.geometry.fundamental.compiled_loop`, so both take the same logarithms (the
    C library's: numpy's vectorised ``log`` may differ from it in the last bit)."""
    C = (1 - delta) * math.log((1 - delta) / (1 - epsilon)) + delta * math.log(delta / epsilon)
    A0 = model_time * C / max(models_per_sample, 1e-9) + 1.0
    A = A0
    for _ in range(20):
        A = A0 + math.log(A)
    return A


@numba.njit(cache=True, nogil=True)
def sprt_logs(A: float, delta: float, epsilon: float) -> tuple[float, float, float]:
    """(log A, log(delta / eps), log((1 - delta) / (1 - eps))), the SPRT kernel's arguments;
    (inf, 0, 0) when A is infinite (SPRT off)."""
    if not math.isfinite(A):
        return math.inf, 0.0, 0.0
    return (
        math.log(A),
        math.log(delta / epsilon),
        math.log((1 - delta) / (1 - epsilon)),
    )


@lru_cache(maxsize=16)
def reading_order(n: int) -> np.ndarray:
    """(n,) int64: the SPRT's fixed pseudo-random order of reading n points (its own generator,
    seeded with n, so the run's draws are untouched). Cached, as every run over n matches reads
    them in the same order: callers must not write to it (it stays writeable because numba
    compiles read-only arrays as another type)."""
    return np.random.default_rng(n).permutation(n).astype(np.int64)


class Sprt:
    """Adaptive SPRT / bail-out state of one run (shared by the arms: they score the same
    points). Keeps epsilon (best model's inlier ratio), delta (inliers per point read in
    SPRT-rejected models) and the threshold A; counts points read."""

    def __init__(self, options: SamplingOptions, n: int) -> None:
        self.opt = options
        # a fixed pseudo-random reading order: the points come best first, and reading them in
        # that order would bias the SPRT; its own generator leaves the run's draws unchanged, so
        # the bail-out alone reproduces the plain run exactly
        self.order = reading_order(n)
        self.delta = options.sprt_delta
        self.epsilon = 0.0
        self.A = np.inf
        self.rej_inliers = 0
        self.rej_read = 0
        self.models = 0
        self.samples = 0
        self.points_read = 0  #: points verified by minimal-sample scoring (all models)
        self.rejected = 0  #: models rejected by the SPRT

    def update(self, best_count: int, n: int) -> None:
        """New epsilon / delta: recompute A (SPRT off while epsilon <= 1.5 delta)."""
        if not self.opt.sprt:
            return
        eps = min(best_count / n, 0.999) if n else 0.0
        if self.rej_read >= 50:  # enough evidence to replace the initial delta
            self.delta = min(0.5, max(1e-4, self.rej_inliers / self.rej_read))
        self.epsilon = eps
        if eps <= 1.5 * self.delta:
            self.A = np.inf
        else:
            ms = self.models / self.samples if self.samples else 1.0
            self.A = sprt_threshold(eps, self.delta, float(self.opt.sprt_model_time), ms)

    def logs(self) -> tuple[float, float, float]:
        """(log A, log(delta / eps), log((1 - delta) / (1 - eps))) for the kernel."""
        return sprt_logs(float(self.A), float(self.delta), float(self.epsilon))
