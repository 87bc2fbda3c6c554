"""The compiled rounds of :class:`~sepfm_ros.geometry.fundamental.compiled_loop.CompiledLoop`:
:func:`rounds_kernel` runs the robust loop's rounds (sampling, the minimal solves, SPRT and
bail-out scoring, offers, local optimisation, the race and the stop) for F arms, to the bit as
the Python rounds of :mod:`~sepfm_ros.geometry.robust.loop` run them, with the state in small
arrays (:data:`INT_STATE`, :data:`FLOAT_STATE`, :data:`ARM_INT_STATE`, :data:`ARM_FLOAT_STATE`).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from sepfm_ros.geometry.epipolar import distances_kernel, msac_kernel, sprt_msac_kernel
from sepfm_ros.geometry.fundamental.nonlinear import LM_ITERATIONS, LM_MODEL_START, _polish_kernel
from sepfm_ros.geometry.fundamental.problem import solve_samples_kernel
from sepfm_ros.geometry.fundamental.refine import _iterative_refit_kernel
from sepfm_ros.geometry.robust.generator_draws import uniform_draws
from sepfm_ros.geometry.robust.samplers import _floyd_samples, _prosac_samples
from sepfm_ros.geometry.robust.sprt import sprt_logs, sprt_threshold
from sepfm_ros.geometry.robust.stopping import samples_needed
from sepfm_ros.geometry.robust.trials import trials_needed

__all__ = ["ARM_FLOAT_STATE", "ARM_INT_STATE", "FLOAT_STATE", "INT_STATE", "rounds_kernel"]

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
    rng: np.ndarray,
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
    (``generator_draws.generator_address``; it advances in place).
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
        return samples_needed(k, n, ints[BEST_COUNT], A, confidence, max_samples, min_samples)

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
        u = uniform_draws(rng, b, k)
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
