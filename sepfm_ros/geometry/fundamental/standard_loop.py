"""The robust loop of one F arm over all matches, compiled: standard LO-RANSAC with PROSAC, the
SPRT and the bail-out, local optimisation and the adaptive stop F(k, r), in one call that holds
the GIL only to enter and to return.

:class:`CompiledLoop` is a :class:`~sepfm_ros.geometry.robust.loop.Loop` whose rounds run in
:func:`rounds_kernel` when it has a single :class:`FundamentalProblem` arm scored by MSAC (the
standard loop of :meth:`FundamentalTask.standard_loop`: the paper's escape, ``ransac7`` and
``ransac8``, and the separable method's fallback); any other loop runs the generic Python
rounds. The kernel is the Python loop's own sequence of steps, kept to the bit: the same draws
from the same generator (numba reads numpy's bit generator in place, so the generator has
advanced as far afterwards), the same kernels, the same decisions, and the same logarithms
(:func:`~sepfm_ros.geometry.robust.sprt.sprt_threshold` is compiled and shared). The loop's
state crosses the boundary as two small arrays (:data:`INT_STATE`, :data:`FLOAT_STATE`) and
three models, so a run may be split into calls (:meth:`Loop.start`, :meth:`Loop.resume`,
:meth:`Loop.run`) as the escape's probe does.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from sepfm_ros.geometry.epipolar import msac_kernel, sprt_msac_kernel
from sepfm_ros.geometry.fundamental.nonlinear import LM_ITERATIONS, LM_MODEL_START, _polish_kernel
from sepfm_ros.geometry.fundamental.problem import FundamentalProblem, solve_samples_kernel
from sepfm_ros.geometry.fundamental.refine import _iterative_refit_kernel
from sepfm_ros.geometry.robust.loop import Loop, RansacResult
from sepfm_ros.geometry.robust.samplers import _floyd_samples, _prosac_samples
from sepfm_ros.geometry.robust.sprt import sprt_logs, sprt_threshold
from sepfm_ros.geometry.robust.trials import trial_count, trials_needed

__all__ = ["CompiledLoop", "FLOAT_STATE", "INT_STATE", "rounds_kernel"]

#: Names of the int64 state of :func:`rounds_kernel`, in order (the arm's, the best model's,
#: the loop's, the budget's, the PROSAC sampler's and the SPRT's counters).
INT_STATE = (
    "samples", "arm_best_count", "raw_count", "best_count", "leader", "extra_lo", "hypotheses",
    "budget_used", "prosac_t", "rej_inliers", "rej_read", "sprt_models", "sprt_samples",
    "points_read", "rejected",
)  # fmt: skip
#: Names of the float64 state of :func:`rounds_kernel`, in order.
FLOAT_STATE = ("arm_cost", "top_cost", "best_cost", "delta", "epsilon", "A")
(
    SAMPLES, ARM_BEST_COUNT, RAW_COUNT, BEST_COUNT, LEADER, EXTRA_LO, HYPOTHESES, BUDGET_USED,
    PROSAC_T, REJ_INLIERS, REJ_READ, SPRT_MODELS, SPRT_SAMPLES, POINTS_READ, REJECTED,
) = range(len(INT_STATE))  # fmt: skip
ARM_COST, TOP_COST, BEST_COST, DELTA, EPSILON, SPRT_A = range(len(FLOAT_STATE))

#: :func:`rounds_kernel`'s modes: rounds without local optimisation until a number of samples
#: (:meth:`Loop.start`), local optimisation of the arm's best minimal-sample model
#: (:meth:`Loop.resume`), rounds to the end (:meth:`Loop.run`).
PROBE, RESUME, RUN = 0, 1, 2


@numba.njit(cache=True, nogil=True)
def _needed(
    k: int, n: int, count: int, A: float, confidence: float, max_samples: int, min_samples: int
) -> int:
    """``StoppingRule.needed``: samples of k points needed at the best model's ``count``."""
    count = max(count, 0)
    if math.isfinite(A) and n > 0:
        w = min(1.0, count / n) ** float(k) * (1.0 - 1.0 / A)
        need = int(min(trial_count(1, w, confidence), float(max_samples)))
    else:
        need = trials_needed(k, count, n, confidence, max_samples)
    return max(need, min_samples)


@numba.njit(cache=True, nogil=True)
def _sprt_update(
    ints: np.ndarray, floats: np.ndarray, best_count: int, n: int, sprt: bool, model_time: float
) -> None:
    """``Sprt.update``: new epsilon and delta, and A (inf while epsilon <= 1.5 delta)."""
    if not sprt:
        return
    eps = min(best_count / n, 0.999) if n else 0.0
    if ints[REJ_READ] >= 50:
        floats[DELTA] = min(0.5, max(1e-4, ints[REJ_INLIERS] / ints[REJ_READ]))
    floats[EPSILON] = eps
    if eps <= 1.5 * floats[DELTA]:
        floats[SPRT_A] = math.inf
    else:
        s = ints[SPRT_SAMPLES]
        ms = ints[SPRT_MODELS] / s if s else 1.0
        floats[SPRT_A] = sprt_threshold(eps, floats[DELTA], model_time, ms)


@numba.njit(cache=True, nogil=True)
def _offer(
    models: np.ndarray,
    cost: np.ndarray,
    count: np.ndarray,
    ints: np.ndarray,
    floats: np.ndarray,
    top_model: np.ndarray,
    best_model: np.ndarray,
    n: int,
    sprt: bool,
    model_time: float,
) -> int:
    """``Loop.offer`` of the single arm: index of the cheapest of the scored (K, 3, 3) models;
    updates the arm's and the best model (and the SPRT with the latter)."""
    ints[HYPOTHESES] += models.shape[0]
    i = int(np.argmin(cost))
    ints[ARM_BEST_COUNT] = max(ints[ARM_BEST_COUNT], int(count.max()))
    if cost[i] < floats[TOP_COST]:
        top_model[:, :] = models[i]
        floats[TOP_COST] = cost[i]
    if cost[i] < floats[BEST_COST]:
        best_model[:, :] = models[i]
        floats[BEST_COST] = cost[i]
        ints[BEST_COUNT] = count[i]
        ints[LEADER] = 0
        _sprt_update(ints, floats, ints[BEST_COUNT], n, sprt, model_time)
    return i


@numba.njit(cache=True, nogil=True)
def rounds_kernel(
    mode: int,
    target: int,
    rng: np.random.Generator,
    X1: np.ndarray,
    X2: np.ndarray,
    x1: np.ndarray,
    x2: np.ndarray,
    T1: np.ndarray,
    T2: np.ndarray,
    lo_X1: np.ndarray,
    lo_X2: np.ndarray,
    lo_x1: np.ndarray,
    lo_x2: np.ndarray,
    fixed1: np.ndarray,
    fixed2: np.ndarray,
    pool: np.ndarray,
    schedule: np.ndarray,
    order: np.ndarray,
    ordered: np.ndarray,
    flags: np.ndarray,
    params: np.ndarray,
    sizes: np.ndarray,
    lo_factors: np.ndarray,
    ints: np.ndarray,
    floats: np.ndarray,
    arm_model: np.ndarray,
    top_model: np.ndarray,
    best_model: np.ndarray,
) -> bool:
    """Rounds of the single-arm loop (see the module); True when it converged.

    mode: :data:`PROBE` (rounds without local optimisation until ``target`` samples, the stop
    or the budget's end), :data:`RESUME` (one local optimisation of the arm's best
    minimal-sample model, when it has one) or :data:`RUN` (rounds until the stop or the
    budget's end). rng: the run's generator (advanced in place).
    X1, X2: (3, N) homogeneous px; x1, x2: (N, 2) normalised by T1, T2 (3, 3): the matches
    scored. lo_*: the matches local optimisation fits on (same T1, T2). fixed1, fixed2:
    (f, 2) normalised fixed correspondences. pool: (P,) sampled indices, best first;
    schedule: PROSAC's T'_n (empty: uniform samples). order, ordered: the SPRT's reading order
    (N,) and the points in it (4, N).
    flags (bool): seven-point, oriented check, PROSAC, SPRT object present (SPRT or bail-out),
    SPRT, bail-out, the LM polish. params (float): threshold, confidence, extra-LO ratio, the
    SPRT's model time. sizes (int): k, n, max_samples, min_samples, batch, max_extra_lo,
    IRLS iterations, budget limit. lo_factors: refit threshold factors.
    ints, floats (:data:`INT_STATE`, :data:`FLOAT_STATE`), arm_model, top_model, best_model
    (3, 3): the state, read and written.
    """
    seven, oriented, prosac, has_sprt, sprt, bailout, lo_lm = (
        flags[0], flags[1], flags[2], flags[3], flags[4], flags[5], flags[6],
    )  # fmt: skip
    threshold, confidence, extra_lo_ratio, model_time = params[0], params[1], params[2], params[3]
    k, n, max_samples, min_samples = sizes[0], sizes[1], sizes[2], sizes[3]
    batch, max_extra_lo, irls, limit = sizes[4], sizes[5], sizes[6], sizes[7]
    P = pool.shape[0]

    def needed() -> int:
        A = floats[SPRT_A] if has_sprt else math.inf
        return _needed(k, n, ints[BEST_COUNT], A, confidence, max_samples, min_samples)

    def pooled() -> float:
        if ints[LEADER] < 0 or ints[SAMPLES] == 0:
            return 0.0
        return float(ints[SAMPLES])

    def converged() -> bool:
        return ints[LEADER] >= 0 and pooled() >= needed()

    def budget_left() -> int:
        return max(0, limit - ints[BUDGET_USED])

    def local_optimization(model: np.ndarray, cost: float) -> None:
        lo = _iterative_refit_kernel(
            model, lo_X1, lo_X2, lo_x1, lo_x2, T1, T2, threshold, lo_factors, irls
        )
        start = model
        lo_cost, lo_count = msac_kernel(lo, X1, X2, threshold)
        if lo.shape[0] > 0 and lo_cost.min() < cost:
            start = lo[int(np.argmin(lo_cost))].copy()
        if lo_lm:
            refined = _polish_kernel(
                model, start, lo_x1, lo_x2, lo_X1, lo_X2, T1, T2, threshold, LM_ITERATIONS,
                LM_MODEL_START,
            )  # fmt: skip
            r_cost, r_count = msac_kernel(refined, X1, X2, threshold)
            _offer(refined, r_cost, r_count, ints, floats, top_model, best_model, n, sprt,
                   model_time)  # fmt: skip
        elif lo.shape[0] > 0:
            _offer(lo, lo_cost, lo_count, ints, floats, top_model, best_model, n, sprt,
                   model_time)  # fmt: skip

    def sample_arm(b: int, local: bool) -> None:
        u = rng.random((b, k))
        if prosac:
            idx = _prosac_samples(u, ints[PROSAC_T], P, schedule)
            ints[PROSAC_T] += b
        else:
            if P < k:
                raise ValueError("cannot draw distinct points from a pool smaller than a sample")
            idx = _floyd_samples(u, P)
        smp = np.empty((b, k), dtype=np.int64)
        for r in range(b):
            for c in range(k):
                smp[r, c] = pool[idx[r, c]]
        ints[SAMPLES] += b
        ints[BUDGET_USED] += b
        models, _ = solve_samples_kernel(fixed1, fixed2, x1, x2, smp, T1, T2, seven, oriented)
        if has_sprt:
            ints[SPRT_SAMPLES] += b
            ints[SPRT_MODELS] += models.shape[0]
        if models.shape[0] == 0:
            return
        if has_sprt:
            bail_cost, bail_count = math.inf, 0
            if bailout and math.isfinite(floats[ARM_COST]):
                bail_cost = floats[ARM_COST]
                bail_count = ints[ARM_BEST_COUNT] + 1
                if ints[EXTRA_LO] < max_extra_lo:
                    bail_count = min(bail_count, int(math.ceil(extra_lo_ratio * ints[RAW_COUNT])))
            log_A, log_in, log_out = sprt_logs(floats[SPRT_A], floats[DELTA], floats[EPSILON])
            cost, count, read, rejected = sprt_msac_kernel(
                models, X1, X2, threshold, order, ordered, log_A, log_in, log_out, bail_cost,
                bail_count,
            )  # fmt: skip
            ints[POINTS_READ] += read.sum()
            for m in range(models.shape[0]):
                if rejected[m]:
                    ints[REJECTED] += 1
                    ints[REJ_INLIERS] += count[m]
                    ints[REJ_READ] += read[m]
        else:
            cost, count = msac_kernel(models, X1, X2, threshold)
        i = _offer(models, cost, count, ints, floats, top_model, best_model, n, sprt, model_time)
        if has_sprt and not math.isfinite(cost[i]):
            return
        if cost[i] < floats[ARM_COST]:
            arm_model[:, :] = models[i]
            floats[ARM_COST] = cost[i]
            ints[RAW_COUNT] = count[i]
            if local:
                local_optimization(models[i].copy(), cost[i])
        elif (
            local and ints[EXTRA_LO] < max_extra_lo and count[i] >= extra_lo_ratio * ints[RAW_COUNT]
        ):
            ints[EXTRA_LO] += 1
            local_optimization(models[i].copy(), cost[i])

    def sample_round(local: bool) -> None:
        pace = max(1, ints[SAMPLES])
        need = needed()
        done = pooled()
        if ints[LEADER] >= 0 and done >= need:
            return
        b = max(1, min(int(math.ceil(need - done)), batch, pace))
        b = min(b, budget_left(), max_samples)
        if b > 0:
            sample_arm(b, local)

    if mode == RESUME:
        if math.isfinite(floats[ARM_COST]):
            local_optimization(arm_model.copy(), floats[ARM_COST])
        return converged()
    local = mode == RUN
    while mode == RUN or ints[SAMPLES] < target:
        sample_round(local)
        if converged():
            return True
        if budget_left() <= 0:
            return False
    return converged()


class CompiledLoop(Loop):
    """A :class:`Loop` whose rounds run in :func:`rounds_kernel` when its only arm is a
    :class:`FundamentalProblem` over all matches scored by MSAC (see the module); the same
    results to the bit as the generic rounds, which it runs otherwise."""

    def compiled(self) -> bool:
        """Whether this run's rounds can be compiled: one arm, of the kind the kernel runs."""
        if len(self.arms) != 1:
            return False
        problem = self.arms[0].problem
        return (
            type(problem) is FundamentalProblem
            and problem.scoring == "msac"
            and len(problem.f1) == 0
            and self.arms[0].share >= 1.0
        )

    def start(self, samples: int) -> bool:
        if not self.compiled():
            return super().start(samples)
        return self._rounds(PROBE, samples)

    def resume(self) -> None:
        if not self.compiled():
            super().resume()
            return
        self._rounds(RESUME, 0)

    def run(self) -> RansacResult:
        if not self.compiled():
            return super().run()
        converged = self._rounds(RUN, 0)
        best, sprt = self.best, self.sprt
        return RansacResult(
            model=best.model,
            cost=best.cost,
            count=max(best.count, 0),
            leader=best.leader,
            hypotheses=self.hypotheses,
            samples=[arm.samples for arm in self.arms],
            dropped=self.race.dropped,
            converged=converged,
            points_read=sprt.points_read if sprt else 0,
            rejected=sprt.rejected if sprt else 0,
        )

    def _rounds(self, mode: int, target: int) -> bool:
        """One call of :func:`rounds_kernel` from this loop's state, written back after it."""
        arm, best, sprt, opt = self.arms[0], self.best, self.sprt, self.sampling
        problem: FundamentalProblem = arm.problem  # type: ignore[assignment]
        data, lo = problem.data, problem.lo_data
        ints = np.array(
            [
                arm.samples, arm.best_count, arm.raw_count, best.count, best.leader,
                self.extra_lo, self.hypotheses, self.budget.used,
                arm.sampler.t if arm.sampler is not None else 0,
                sprt.rej_inliers if sprt else 0, sprt.rej_read if sprt else 0,
                sprt.models if sprt else 0, sprt.samples if sprt else 0,
                sprt.points_read if sprt else 0, sprt.rejected if sprt else 0,
            ],
            dtype=np.int64,
        )  # fmt: skip
        floats = np.array(
            [
                arm.cost, arm.top_cost, best.cost, sprt.delta if sprt else 0.0,
                sprt.epsilon if sprt else 0.0, sprt.A if sprt else math.inf,
            ],
            dtype=np.float64,
        )  # fmt: skip
        models = [_model_or_zeros(m) for m in (arm.model, arm.top_model, best.model)]
        order = sprt.order if sprt else np.zeros(0, dtype=np.int64)
        ordered = data.in_order(order) if sprt else np.zeros((4, 0))
        schedule = arm.sampler.schedule if arm.sampler is not None else np.zeros(0, np.int64)
        flags = np.array(
            [
                problem.solver == "seven", problem.oriented, arm.sampler is not None,
                sprt is not None, opt.sprt, opt.bailout, bool(problem.lo_lm),
            ]
        )  # fmt: skip
        params = np.array(
            [problem.threshold, self.stopping.confidence, self.extra_lo_ratio,
             float(opt.sprt_model_time)]
        )  # fmt: skip
        sizes = np.array(
            [
                problem.sample_size, problem.n, self.stopping.max_samples,
                self.stopping.min_samples, self.batch, self.max_extra_lo, problem.lo_irls,
                self.budget.limit,
            ],
            dtype=np.int64,
        )  # fmt: skip
        converged = bool(
            rounds_kernel(
                mode, int(target), self.rng, data.X1, data.X2, data.x1, data.x2, data.T1,
                data.T2, lo.X1, lo.X2, lo.x1, lo.x2, problem.f1, problem.f2, problem.pool,
                schedule, order, ordered, flags, params, sizes,
                np.asarray(problem.lo_factors, dtype=np.float64), ints, floats, *models,
            )
        )  # fmt: skip
        self._write_back(ints, floats, models)
        return converged

    def _write_back(self, ints: np.ndarray, floats: np.ndarray, models: list[np.ndarray]) -> None:
        """The kernel's state into this loop's objects (models only where they changed)."""
        arm, best, sprt = self.arms[0], self.best, self.sprt
        s = dict(zip(INT_STATE, (int(v) for v in ints), strict=True))
        f = dict(zip(FLOAT_STATE, (float(v) for v in floats), strict=True))
        if f["arm_cost"] != arm.cost:
            arm.model = models[0]
        if f["top_cost"] != arm.top_cost:
            arm.top_model = models[1]
        if f["best_cost"] != best.cost or s["leader"] != best.leader:
            best.model = models[2]
        arm.samples, arm.best_count, arm.raw_count = (
            s["samples"],
            s["arm_best_count"],
            s["raw_count"],
        )
        arm.cost, arm.top_cost = f["arm_cost"], f["top_cost"]
        best.cost, best.count, best.leader = f["best_cost"], s["best_count"], s["leader"]
        self.extra_lo, self.hypotheses = s["extra_lo"], s["hypotheses"]
        self.budget.used = s["budget_used"]
        if arm.sampler is not None:
            arm.sampler.t = s["prosac_t"]
        if sprt is not None:
            sprt.rej_inliers, sprt.rej_read = s["rej_inliers"], s["rej_read"]
            sprt.models, sprt.samples = s["sprt_models"], s["sprt_samples"]
            sprt.points_read, sprt.rejected = s["points_read"], s["rejected"]
            sprt.delta, sprt.epsilon, sprt.A = f["delta"], f["epsilon"], f["A"]


def _model_or_zeros(model: np.ndarray | None) -> np.ndarray:
    """A writable (3, 3) float64 copy of ``model`` (zeros for None)."""
    if model is None:
        return np.zeros((3, 3))
    return np.array(model, dtype=np.float64).reshape(3, 3)
