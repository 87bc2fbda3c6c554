"""The robust loop over F arms, compiled: LO-RANSAC with PROSAC, the SPRT and the bail-out, local
optimisation, the race of arms and the adaptive stop F(k, r), in calls that hold the GIL only to
enter and to return.

:class:`CompiledLoop` is a :class:`~sepfm_ros.geometry.robust.loop.Loop` whose rounds run in
:func:`rounds_kernel` while its arms are :class:`FundamentalProblem` arms scored by MSAC that
solve their samples with their fixed points alone (the standard loop of
:meth:`FundamentalTask.standard_loop`: the paper's escape, ``ransac7``, ``ransac8`` and the
fallback; and the separable method's stage-2 race at its default options), and the race pools
by support. A kernel call returns when the run ends or when the race's schedule lets the next
arm join: joining runs Python (the separable method builds an arm with stage 1 only when it
joins), and the next call goes on with the new arm. Other loops run the generic Python rounds;
a loop may switch to them between calls, as the state lives in the loop's own objects.

The kernel is the Python loop's own sequence of steps, kept to the bit: the same draws from the
same generator (numba reads numpy's bit generator in place, so the generator has advanced as
far afterwards), the same kernels, the same decisions, and the same logarithms (the C
library's, in both). The state crosses the boundary as small arrays (:data:`INT_STATE`,
:data:`FLOAT_STATE`, :data:`ARM_INT_STATE`, :data:`ARM_FLOAT_STATE`) and models.
"""

from __future__ import annotations

import math
from typing import Any

import numba
import numpy as np

from sepfm_ros.geometry.epipolar import distances_kernel, msac_kernel, sprt_msac_kernel
from sepfm_ros.geometry.fundamental.nonlinear import LM_ITERATIONS, LM_MODEL_START, _polish_kernel
from sepfm_ros.geometry.fundamental.problem import FundamentalProblem, solve_samples_kernel
from sepfm_ros.geometry.fundamental.refine import _iterative_refit_kernel
from sepfm_ros.geometry.robust.loop import Loop, RansacResult
from sepfm_ros.geometry.robust.samplers import _floyd_samples, _prosac_samples
from sepfm_ros.geometry.robust.sprt import sprt_logs, sprt_threshold
from sepfm_ros.geometry.robust.trials import trial_count, trials_needed

__all__ = [
    "ARM_FLOAT_STATE",
    "ARM_INT_STATE",
    "CompiledLoop",
    "FLOAT_STATE",
    "INT_STATE",
    "rounds_kernel",
]

#: Names of the run's int64 state in :func:`rounds_kernel`, in order.
INT_STATE = (
    "best_count", "leader", "extra_lo", "hypotheses", "budget_used", "rej_inliers", "rej_read",
    "sprt_models", "sprt_samples", "points_read", "rejected", "next_join", "n_active",
    "n_dropped",
)  # fmt: skip
#: Names of the run's float64 state, in order.
FLOAT_STATE = ("best_cost", "delta", "epsilon", "A")
#: Names of each arm's int64 state (a row per arm), in order.
ARM_INT_STATE = ("samples", "best_count", "raw_count", "prosac_t", "checked")
#: Names of each arm's float64 state, in order.
ARM_FLOAT_STATE = ("cost", "top_cost")
(
    BEST_COUNT, LEADER, EXTRA_LO, HYPOTHESES, BUDGET_USED, REJ_INLIERS, REJ_READ, SPRT_MODELS,
    SPRT_SAMPLES, POINTS_READ, REJECTED, NEXT_JOIN, N_ACTIVE, N_DROPPED,
) = range(len(INT_STATE))  # fmt: skip
BEST_COST, DELTA, EPSILON, SPRT_A = range(len(FLOAT_STATE))
SAMPLES, ARM_BEST, RAW_COUNT, PROSAC_T, CHECKED = range(len(ARM_INT_STATE))
COST, TOP_COST = range(len(ARM_FLOAT_STATE))
#: Columns of each arm's static ints: sample size, fixed points, PROSAC, fixed-point check.
K, FIXED, PROSAC, FIXED_CHECK = range(4)

#: :func:`rounds_kernel`'s modes: rounds without local optimisation of minimal-sample models
#: until a number of samples (:meth:`Loop.start`), local optimisation of every arm's best
#: minimal-sample model (:meth:`Loop.resume`), rounds to the end (:meth:`Loop.run`).
PROBE, RESUME, RUN = 0, 1, 2
#: What a call of :func:`rounds_kernel` ended with: not converged (the budget's end, no arm
#: left, or the probe's samples drawn), converged, or the next arm may join.
NOT_CONVERGED, CONVERGED, JOIN = 0, 1, 2


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
    ints: np.ndarray, floats: np.ndarray, n: int, sprt: bool, model_time: float
) -> None:
    """``Sprt.update`` at the best model's count: new epsilon and delta, and A (inf while
    epsilon <= 1.5 delta)."""
    if not sprt:
        return
    eps = min(ints[BEST_COUNT] / n, 0.999) if n else 0.0
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
    a: int,
    models: np.ndarray,
    cost: np.ndarray,
    count: np.ndarray,
    ints: np.ndarray,
    floats: np.ndarray,
    best_model: np.ndarray,
    arm_ints: np.ndarray,
    arm_floats: np.ndarray,
    top_models: np.ndarray,
    n: int,
    sprt: bool,
    model_time: float,
) -> int:
    """``Loop.offer``: index of the cheapest of arm ``a``'s scored (K, 3, 3) models; updates the
    arm's best count and top model and the best model (and the SPRT with it). The state
    arrays are :func:`rounds_kernel`'s."""
    ints[HYPOTHESES] += models.shape[0]
    i = int(np.argmin(cost))
    arm_ints[a, ARM_BEST] = max(arm_ints[a, ARM_BEST], int(count.max()))
    if cost[i] < arm_floats[a, TOP_COST]:
        top_models[a] = models[i]
        arm_floats[a, TOP_COST] = cost[i]
    if cost[i] < floats[BEST_COST]:
        best_model[:, :] = models[i]
        floats[BEST_COST] = cost[i]
        ints[BEST_COUNT] = count[i]
        ints[LEADER] = a
        _sprt_update(ints, floats, n, sprt, model_time)
    return i


@numba.njit(cache=True, nogil=True)
def _local_optimization(
    a: int,
    model: np.ndarray,
    cost: float,
    X1: np.ndarray,
    X2: np.ndarray,
    T1: np.ndarray,
    T2: np.ndarray,
    lo_X1: np.ndarray,
    lo_X2: np.ndarray,
    lo_x1: np.ndarray,
    lo_x2: np.ndarray,
    threshold: float,
    lo_factors: np.ndarray,
    irls: int,
    lo_lm: bool,
    ints: np.ndarray,
    floats: np.ndarray,
    best_model: np.ndarray,
    arm_ints: np.ndarray,
    arm_floats: np.ndarray,
    top_models: np.ndarray,
    n: int,
    sprt: bool,
    model_time: float,
) -> None:
    """``Loop.local_optimization`` of arm ``a``'s ``model`` (3, 3) of cost ``cost``: its refits
    are scored, and with the LM polish (``lo_lm``) the polish of the best of ``model`` and its
    refits is offered in their place. Arguments: :func:`rounds_kernel`'s."""
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
        _offer(a, refined, r_cost, r_count, ints, floats, best_model, arm_ints, arm_floats,
               top_models, n, sprt, model_time)  # fmt: skip
    elif lo.shape[0] > 0:
        _offer(a, lo, lo_cost, lo_count, ints, floats, best_model, arm_ints, arm_floats,
               top_models, n, sprt, model_time)  # fmt: skip


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
    order: np.ndarray,
    ordered: np.ndarray,
    arm_static: np.ndarray,
    arm_share: np.ndarray,
    arm_fixed_tol: np.ndarray,
    fixed1: np.ndarray,
    fixed2: np.ndarray,
    fixed_px1: np.ndarray,
    fixed_px2: np.ndarray,
    pools: np.ndarray,
    pool_start: np.ndarray,
    schedules: np.ndarray,
    schedule_start: np.ndarray,
    flags: np.ndarray,
    params: np.ndarray,
    sizes: np.ndarray,
    lo_factors: np.ndarray,
    ints: np.ndarray,
    floats: np.ndarray,
    best_model: np.ndarray,
    arm_models: np.ndarray,
    top_models: np.ndarray,
    arm_ints: np.ndarray,
    arm_floats: np.ndarray,
    active: np.ndarray,
    dropped: np.ndarray,
) -> int:
    """Rounds of the loop (see the module): :data:`NOT_CONVERGED`, :data:`CONVERGED` or
    :data:`JOIN`.

    mode: :data:`PROBE` (rounds without local optimisation of minimal-sample models until
    ``target`` samples in all), :data:`RESUME` or :data:`RUN`. rng: the run's generator
    (advanced in place).
    X1, X2: (3, N) homogeneous px; x1, x2: (N, 2) normalised by T1, T2 (3, 3): the matches
    scored. lo_*: the matches local optimisation fits on (same T1, T2). order, ordered: the
    SPRT's reading order (N,) and the points in it (4, N).
    Per arm a (A arms): arm_static (A, 4) ints (:data:`K`, :data:`FIXED`, :data:`PROSAC`,
    :data:`FIXED_CHECK`); arm_share (A,) its most share of all samples; arm_fixed_tol (A,) px;
    fixed1, fixed2 (A, f, 2) its normalised fixed correspondences (the first ``FIXED`` rows);
    fixed_px1, fixed_px2 (A, 3, f) the same as homogeneous px columns; its pool
    pools[pool_start[a]:pool_start[a + 1]] (best first) and PROSAC schedule
    schedules[schedule_start[a]:schedule_start[a + 1]].
    flags (bool): seven-point, oriented check, SPRT object present (SPRT or bail-out), SPRT,
    bail-out, the LM polish. params (float): threshold, confidence, extra-LO ratio, the SPRT's
    model time, the race's drop ratio, drop alpha and pool ratio. sizes (int): n,
    max_samples, min_samples, batch, max_extra_lo, IRLS iterations, budget limit, the points
    of a sample without fixed points. lo_factors: refit threshold factors.
    The state, read and written: ints, floats (:data:`INT_STATE`, :data:`FLOAT_STATE`),
    best_model (3, 3), arm_models and top_models (A, 3, 3), arm_ints, arm_floats (A, ...)
    (:data:`ARM_INT_STATE`, :data:`ARM_FLOAT_STATE`), active (A,) the active arms'
    indices in order (the first ``n_active``), dropped (A,) the dropped ones' in order.
    """
    seven, oriented, has_sprt, sprt, bailout, lo_lm = (
        flags[0], flags[1], flags[2], flags[3], flags[4], flags[5],
    )  # fmt: skip
    threshold, confidence, extra_lo_ratio, model_time = params[0], params[1], params[2], params[3]
    drop_ratio, drop_alpha, pool_ratio = params[4], params[5], params[6]
    n, max_samples, min_samples, batch = sizes[0], sizes[1], sizes[2], sizes[3]
    max_extra_lo, irls, limit, free_k = sizes[4], sizes[5], sizes[6], sizes[7]
    n_arms = arm_static.shape[0]

    def total() -> int:
        return int(arm_ints[:, SAMPLES].sum())

    def budget_left() -> int:
        return max(0, limit - ints[BUDGET_USED])

    def needed(a: int) -> int:
        A = floats[SPRT_A] if has_sprt else math.inf
        k = arm_static[a, K]
        return _needed(k, n, ints[BEST_COUNT], A, confidence, max_samples, min_samples)

    def consistent(a: int) -> bool:
        if ints[LEADER] < 0 or not arm_static[a, FIXED_CHECK]:
            return True
        f = arm_static[a, FIXED]
        F = best_model.copy().reshape(1, 3, 3)
        X1f = np.ascontiguousarray(fixed_px1[a, :, :f])
        X2f = np.ascontiguousarray(fixed_px2[a, :, :f])
        d = distances_kernel(F, X1f, X2f)[0]
        return bool(np.all(d < arm_fixed_tol[a]))

    def pools_with_best(b: int) -> bool:
        if not consistent(b):
            return False
        if b == ints[LEADER]:
            return True
        return arm_ints[b, ARM_BEST] >= pool_ratio * ints[BEST_COUNT]

    def pooled(a: int) -> float:
        if ints[LEADER] < 0:
            return 0.0
        need = needed(a)
        done = 0.0
        for b in range(n_arms):
            s = arm_ints[b, SAMPLES]
            if s and pools_with_best(b):
                nb = needed(b)
                done += s if nb == need else s * need / nb
        return done

    def converged() -> bool:
        lead = ints[LEADER]
        return lead >= 0 and pooled(lead) >= needed(lead)

    def share_left(a: int) -> int:
        if arm_share[a] >= 1.0:
            return max_samples
        unshared = False
        for j in range(ints[N_ACTIVE]):
            if arm_share[active[j]] >= 1.0:
                unshared = True
        if not unshared:
            return max_samples
        others = total() - arm_ints[a, SAMPLES]
        return int(arm_share[a] / (1.0 - arm_share[a]) * others) - arm_ints[a, SAMPLES]

    def offer(a: int, models: np.ndarray, cost: np.ndarray, count: np.ndarray) -> int:
        return _offer(
            a, models, cost, count, ints, floats, best_model, arm_ints, arm_floats, top_models,
            n, sprt, model_time,
        )  # fmt: skip

    def local_optimization(a: int, model: np.ndarray, cost: float) -> None:
        _local_optimization(
            a, model, cost, X1, X2, T1, T2, lo_X1, lo_X2, lo_x1, lo_x2, threshold, lo_factors,
            irls, lo_lm, ints, floats, best_model, arm_ints, arm_floats, top_models, n, sprt,
            model_time,
        )  # fmt: skip

    def sample_arm(a: int, b: int, local: bool) -> None:
        k = arm_static[a, K]
        pool = pools[pool_start[a] : pool_start[a + 1]]
        u = rng.random((b, k))
        if arm_static[a, PROSAC]:
            schedule = schedules[schedule_start[a] : schedule_start[a + 1]]
            idx = _prosac_samples(u, arm_ints[a, PROSAC_T], pool.shape[0], schedule)
            arm_ints[a, PROSAC_T] += b
        else:
            if pool.shape[0] < k:
                raise ValueError("cannot draw distinct points from a pool smaller than a sample")
            idx = _floyd_samples(u, pool.shape[0])
        smp = np.empty((b, k), dtype=np.int64)
        for r in range(b):
            for c in range(k):
                smp[r, c] = pool[idx[r, c]]
        arm_ints[a, SAMPLES] += b
        ints[BUDGET_USED] += b
        f = arm_static[a, FIXED]
        models, _ = solve_samples_kernel(
            np.ascontiguousarray(fixed1[a, :f]), np.ascontiguousarray(fixed2[a, :f]), x1, x2,
            smp, T1, T2, seven, oriented,
        )  # fmt: skip
        if has_sprt:
            ints[SPRT_SAMPLES] += b
            ints[SPRT_MODELS] += models.shape[0]
        if models.shape[0] == 0:
            return
        if has_sprt:
            bail_cost, bail_count = math.inf, 0
            if bailout and math.isfinite(arm_floats[a, COST]):
                bail_cost = arm_floats[a, COST]
                bail_count = arm_ints[a, ARM_BEST] + 1
                if ints[EXTRA_LO] < max_extra_lo:
                    bail_count = min(
                        bail_count, int(math.ceil(extra_lo_ratio * arm_ints[a, RAW_COUNT]))
                    )
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
        i = offer(a, models, cost, count)
        if has_sprt and not math.isfinite(cost[i]):
            return
        if cost[i] < arm_floats[a, COST]:
            arm_models[a] = models[i]
            arm_floats[a, COST] = cost[i]
            arm_ints[a, RAW_COUNT] = count[i]
            if local:
                local_optimization(a, models[i].copy(), cost[i])
        elif (
            local
            and ints[EXTRA_LO] < max_extra_lo
            and count[i] >= extra_lo_ratio * arm_ints[a, RAW_COUNT]
        ):
            ints[EXTRA_LO] += 1
            local_optimization(a, models[i].copy(), cost[i])

    def sample_round(local: bool) -> None:
        running = active[: ints[N_ACTIVE]].copy()
        pace = 1
        for a in running:
            pace = max(pace, arm_ints[a, SAMPLES])
        for a in running:
            need = needed(a)
            done = pooled(a)
            if ints[LEADER] >= 0 and done >= need:
                break
            b = max(1, min(int(math.ceil(need - done)), batch, pace))
            b = min(b, budget_left(), share_left(a))
            if b > 0:
                sample_arm(a, b, local)

    def agrees(a: int) -> bool:
        return a == ints[LEADER] or arm_ints[a, ARM_BEST] >= drop_ratio * ints[BEST_COUNT]

    def drop_after(a: int) -> float:
        w = min(1.0, max(ints[BEST_COUNT], 0) / n)
        p_good = w ** float(arm_static[a, K])
        return math.log(drop_alpha) / math.log(max(1e-300, 1.0 - p_good))

    def unfixed_affordable() -> bool:
        count = max(ints[BEST_COUNT], 0)
        return trials_needed(free_k, count, n, confidence, max_samples) <= budget_left()

    def drop(a: int) -> None:
        m = ints[N_ACTIVE]
        j = 0
        for i in range(m):
            if active[i] != a:
                active[j] = active[i]
                j += 1
        ints[N_ACTIVE] = j
        dropped[ints[N_DROPPED]] = a
        ints[N_DROPPED] += 1

    def drop_lagging() -> None:
        if ints[BEST_COUNT] <= 0:
            return
        for a in active[: ints[N_ACTIVE]].copy():
            if not consistent(a) and (arm_ints[a, SAMPLES] >= needed(a) or unfixed_affordable()):
                drop(a)
        if n_arms <= 1:
            return
        for a in active[: ints[N_ACTIVE]].copy():
            if agrees(a) or arm_ints[a, SAMPLES] < drop_after(a):
                continue
            if not arm_ints[a, CHECKED] and math.isfinite(arm_floats[a, COST]):
                arm_ints[a, CHECKED] = 1
                local_optimization(a, arm_models[a].copy(), arm_floats[a, COST])
                if agrees(a):
                    continue
            drop(a)

    if mode == RESUME:
        for a in range(n_arms):
            if math.isfinite(arm_floats[a, COST]):
                local_optimization(a, arm_models[a].copy(), arm_floats[a, COST])
        return CONVERGED if converged() else NOT_CONVERGED
    local = mode == RUN
    while ints[N_ACTIVE] > 0 and (mode == RUN or total() < target):
        sample_round(local)
        if converged():
            return CONVERGED
        if budget_left() <= 0:
            return NOT_CONVERGED
        drop_lagging()
        if total() >= ints[NEXT_JOIN] or ints[N_ACTIVE] == 0:
            return JOIN
    if mode == RUN:
        return NOT_CONVERGED
    return CONVERGED if converged() else NOT_CONVERGED


class CompiledLoop(Loop):
    """A :class:`Loop` whose rounds run in :func:`rounds_kernel` while its arms and race are of
    the kind the kernel runs (see the module); the same results to the bit as the generic
    rounds, which it runs otherwise."""

    #: (number of arms, the kernel's arguments that stay the same for them) (:meth:`_static`)
    _static_args: tuple[int, tuple[Any, ...]] | None = None
    #: the kernel's best, arm and top models, kept from one call to the next (:meth:`_models`)
    _model_arrays: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
    #: the model objects the last call left in the best model and the arms (:meth:`_models`)
    _synced: tuple[Any, list[Any], list[Any]] = (None, [], [])

    def compiled(self) -> bool:
        """Whether the next rounds can be compiled: MSAC arms that solve with their fixed
        points alone, a race that pools by support, no LMedS scale."""
        if not self.arms or self.race.options.pool_rule != "support":
            return False
        return all(
            isinstance(arm.problem, FundamentalProblem)
            and arm.problem.scoring == "msac"
            and arm.problem.plain_solve
            for arm in self.arms
        )

    def start(self, samples: int) -> bool:
        self.local_optimizing = False
        try:
            while self.compiled():
                event = self._rounds(PROBE, samples)
                if event != JOIN:
                    return event == CONVERGED
                self.race.join_on_schedule(self.join)
            return super().start(samples)
        finally:
            self.local_optimizing = True

    def resume(self) -> None:
        if not self.compiled():
            super().resume()
            return
        self._rounds(RESUME, 0)

    def run(self) -> RansacResult:
        while self.compiled():
            event = self._rounds(RUN, 0)
            if event != JOIN:
                return self._result(event == CONVERGED)
            self.race.join_on_schedule(self.join)
        return super().run()

    def _result(self, converged: bool) -> RansacResult:
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

    def _rounds(self, mode: int, target: int) -> int:
        """One call of :func:`rounds_kernel` from this loop's state, written back after it."""
        best, sprt, race, arms = self.best, self.sprt, self.race, self.arms
        static = self._static()
        models = self._models()
        ints = np.array(
            [
                best.count, best.leader, self.extra_lo, self.hypotheses, self.budget.used,
                sprt.rej_inliers if sprt else 0, sprt.rej_read if sprt else 0,
                sprt.models if sprt else 0, sprt.samples if sprt else 0,
                sprt.points_read if sprt else 0, sprt.rejected if sprt else 0,
                race.next_join, len(race.active), len(race.dropped),
            ],
            dtype=np.int64,
        )  # fmt: skip
        floats = np.array(
            [
                best.cost, sprt.delta if sprt else 0.0, sprt.epsilon if sprt else 0.0,
                sprt.A if sprt else math.inf,
            ],
            dtype=np.float64,
        )  # fmt: skip
        arm_ints = np.array(
            [
                (arm.samples, arm.best_count, arm.raw_count,
                 arm.sampler.t if arm.sampler is not None else 0, arm.checked)
                for arm in arms
            ],
            dtype=np.int64,
        )  # fmt: skip
        arm_floats = np.array([(arm.cost, arm.top_cost) for arm in arms], dtype=np.float64)
        n_arms = len(arms)
        active = np.zeros(n_arms, dtype=np.int64)
        active[: len(race.active)] = race.active
        dropped = np.zeros(n_arms, dtype=np.int64)
        dropped[: len(race.dropped)] = race.dropped
        # (mypy cannot count the arguments of the unpacked tuples)
        event = int(
            rounds_kernel(  # type: ignore[call-arg]
                mode, int(target), self.rng, *static, ints, floats, *models, arm_ints,
                arm_floats, active, dropped,
            )
        )  # fmt: skip
        self._write_back(
            models, ints.tolist(), floats.tolist(), arm_ints.tolist(), arm_floats.tolist()
        )
        race.active[:] = active[: ints[N_ACTIVE]].tolist()
        race.dropped[:] = dropped[: ints[N_DROPPED]].tolist()
        return event

    def _write_back(
        self,
        models: tuple[np.ndarray, np.ndarray, np.ndarray],
        ints: list[int],
        floats: list[float],
        arm_ints: list[list[int]],
        arm_floats: list[list[float]],
    ) -> None:
        """The kernel's state into this loop's objects; a model that changed is copied out
        (the kernel's model arrays stay this loop's, for its next call)."""
        best, sprt = self.best, self.sprt
        best_model, arm_models, top_models = models
        if floats[BEST_COST] != best.cost or ints[LEADER] != best.leader:
            best.model = best_model.copy()
        best.cost, best.count, best.leader = floats[BEST_COST], ints[BEST_COUNT], ints[LEADER]
        self.extra_lo, self.hypotheses = ints[EXTRA_LO], ints[HYPOTHESES]
        self.budget.used = ints[BUDGET_USED]
        if sprt is not None:
            sprt.rej_inliers, sprt.rej_read = ints[REJ_INLIERS], ints[REJ_READ]
            sprt.models, sprt.samples = ints[SPRT_MODELS], ints[SPRT_SAMPLES]
            sprt.points_read, sprt.rejected = ints[POINTS_READ], ints[REJECTED]
            sprt.delta, sprt.epsilon, sprt.A = floats[DELTA], floats[EPSILON], floats[SPRT_A]
        for a, arm in enumerate(self.arms):
            samples, best_count, raw_count, t, checked = arm_ints[a]
            cost, top_cost = arm_floats[a]
            if cost != arm.cost:
                arm.model = arm_models[a].copy()
            if top_cost != arm.top_cost:
                arm.top_model = top_models[a].copy()
            arm.samples, arm.best_count, arm.raw_count = samples, best_count, raw_count
            arm.cost, arm.top_cost, arm.checked = cost, top_cost, bool(checked)
            if arm.sampler is not None:
                arm.sampler.t = t
        self._synced = (best.model, [arm.model for arm in self.arms],
                        [arm.top_model for arm in self.arms])  # fmt: skip

    def _models(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The kernel's (3, 3) best model and (A, 3, 3) arm and top models: this loop's arrays
        from its last call, with the models Python set since then copied in."""
        arms = self.arms
        arrays, synced = self._model_arrays, self._synced
        if arrays is None or len(arrays[1]) != len(arms):
            old = arrays
            arrays = (np.zeros((3, 3)), np.zeros((len(arms), 3, 3)), np.zeros((len(arms), 3, 3)))
            if old is not None:
                m = min(len(old[1]), len(arms))
                arrays[0][:] = old[0]
                arrays[1][:m], arrays[2][:m] = old[1][:m], old[2][:m]
            self._model_arrays = arrays
        best_model, arm_models, top_models = arrays
        if self.best.model is not None and self.best.model is not synced[0]:
            best_model[:] = self.best.model
        for a, arm in enumerate(arms):
            known = a < len(synced[1])
            if arm.model is not None and (not known or arm.model is not synced[1][a]):
                arm_models[a] = arm.model
            if arm.top_model is not None and (not known or arm.top_model is not synced[2][a]):
                top_models[a] = arm.top_model
        return arrays

    def _static(self) -> tuple[Any, ...]:
        """The kernel's arguments that do not change during a run for the arms it has now (the
        matches, the arms' fixed points, pools and schedules, the options), made once per
        number of arms."""
        cached = self._static_args
        if cached is not None and cached[0] == len(self.arms):
            return cached[1]
        sprt, opt, arms = self.sprt, self.sampling, self.arms
        problems: list[FundamentalProblem] = [arm.problem for arm in arms]  # type: ignore[misc]
        p0 = problems[0]
        data, lo = p0.data, p0.lo_data
        n_arms = len(arms)
        n_fixed = max(1, max(len(p.f1) for p in problems))
        fixed1 = np.zeros((n_arms, n_fixed, 2))
        fixed2 = np.zeros((n_arms, n_fixed, 2))
        fixed_px1 = np.zeros((n_arms, 3, n_fixed))
        fixed_px2 = np.zeros((n_arms, 3, n_fixed))
        static = np.zeros((n_arms, 4), dtype=np.int64)
        for a, (arm, p) in enumerate(zip(arms, problems, strict=True)):
            f = len(p.f1)
            fixed1[a, :f], fixed2[a, :f] = p.f1, p.f2
            if p.fixed_px is not None:
                fixed_px1[a, :, :f], fixed_px2[a, :, :f] = p.fixed_px
            static[a] = (p.sample_size, f, arm.sampler is not None, p.fixed_px is not None)
        pools = [p.pool for p in problems]
        schedules = [
            arm.sampler.schedule if arm.sampler is not None else np.zeros(0, np.int64)
            for arm in arms
        ]
        order = sprt.order if sprt else np.zeros(0, dtype=np.int64)
        ordered = data.in_order(order) if sprt else np.zeros((4, 0))
        rc = self.race.options
        flags = np.array(
            [p0.solver == "seven", p0.oriented, sprt is not None, opt.sprt, opt.bailout,
             bool(p0.lo_lm)]
        )  # fmt: skip
        params = np.array(
            [p0.threshold, self.stopping.confidence, self.extra_lo_ratio,
             float(opt.sprt_model_time), rc.drop_ratio, rc.drop_alpha, rc.pool_ratio]
        )  # fmt: skip
        sizes = np.array(
            [p0.n, self.stopping.max_samples, self.stopping.min_samples, self.batch,
             self.max_extra_lo, p0.lo_irls, self.budget.limit, p0.free_sample_size()],
            dtype=np.int64,
        )  # fmt: skip
        args = (
            data.X1, data.X2, data.x1, data.x2, data.T1, data.T2, lo.X1, lo.X2, lo.x1, lo.x2,
            order, ordered, static, np.array([arm.share for arm in arms]),
            np.array([p.fixed_tol for p in problems]), fixed1, fixed2, fixed_px1, fixed_px2,
            np.concatenate(pools), _starts(pools), np.concatenate(schedules), _starts(schedules),
            flags, params, sizes, np.asarray(p0.lo_factors, dtype=np.float64),
        )  # fmt: skip
        self._static_args = (n_arms, args)
        return args


def _starts(parts: list[np.ndarray]) -> np.ndarray:
    """(len(parts) + 1,) offsets of each part in their concatenation."""
    out = np.zeros(len(parts) + 1, dtype=np.int64)
    np.cumsum([len(p) for p in parts], out=out[1:])
    return out


def _model_or_zeros(model: np.ndarray | None) -> np.ndarray:
    """A writable (3, 3) float64 copy of ``model`` (zeros for None)."""
    if model is None:
        return np.zeros((3, 3))
    return np.array(model, dtype=np.float64).reshape(3, 3)
