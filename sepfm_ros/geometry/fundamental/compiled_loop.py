"""The robust loop over F arms, compiled: LO-RANSAC with PROSAC, the SPRT and the bail-out, local
optimisation, the race of arms and the adaptive stop F(k, r), in calls that hold the GIL only to
enter and to return.

:class:`CompiledLoop` is a :class:`~sepfm_ros.geometry.robust.loop.Loop` whose rounds run in
the kernel of :mod:`~sepfm_ros.geometry.fundamental.loop_kernel` while its arms are
:class:`FundamentalProblem` arms scored by MSAC that solve their samples with their fixed points
alone (the standard loop of :meth:`FundamentalTask.standard_loop`: the paper's escape,
``ransac7``, ``ransac8`` and the fallback; and the separable method's stage-2 race at its
default options), and the race pools by support. A kernel call returns when the run ends or when
the race's schedule lets the next arm join: joining runs Python (the separable method builds an
arm with stage 1 only when it joins), and the next call goes on with the new arm. Other loops
run the generic Python rounds; a loop may switch to them between calls, as the state lives in
the loop's own objects.

The kernel is the Python loop's own sequence of steps, kept to the bit: the same draws from the
same generator (the kernel calls the bit generator's own ``next_double`` on its state,
``robust.generator_draws``, so the generator has advanced as far afterwards), the same kernels,
the same decisions, and the same logarithms (the C library's, in both). The state crosses the
boundary as small arrays and models, for each call.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from sepfm_ros.geometry.fundamental.loop_kernel import (
    BEST_COST,
    BEST_COUNT,
    BUDGET_USED,
    CONVERGED,
    DELTA,
    EPSILON,
    EXTRA_LO,
    HYPOTHESES,
    JOIN,
    LEADER,
    N_ACTIVE,
    N_DROPPED,
    POINTS_READ,
    PROBE,
    REJ_INLIERS,
    REJ_READ,
    REJECTED,
    RESUME,
    RUN,
    SPRT_A,
    SPRT_MODELS,
    SPRT_SAMPLES,
    rounds_kernel,
)
from sepfm_ros.geometry.fundamental.problem import FundamentalProblem
from sepfm_ros.geometry.robust.generator_draws import generator_address
from sepfm_ros.geometry.robust.loop import Loop, RansacResult

__all__ = ["CompiledLoop"]


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
    #: (the generator, its addresses for the kernel) (:meth:`_rng_address`)
    _rng_cache: tuple[np.random.Generator, np.ndarray] | None = None

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
                return self.result(event == CONVERGED)
            self.race.join_on_schedule(self.join)
        return super().run()

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
                mode, int(target), self._rng_address(), *static, ints, floats, *models, arm_ints,
                arm_floats, active, dropped,
            )
        )  # fmt: skip
        self._write_back(
            models, ints.tolist(), floats.tolist(), arm_ints.tolist(), arm_floats.tolist()
        )
        race.active[:] = active[: ints[N_ACTIVE]].tolist()
        race.dropped[:] = dropped[: ints[N_DROPPED]].tolist()
        return event

    def _rng_address(self) -> np.ndarray:
        """The run's generator as the kernel draws from it (``generator_draws``), made once
        per generator (the loop keeps the generator alive)."""
        cached = self._rng_cache
        if cached is None or cached[0] is not self.rng:
            cached = self._rng_cache = (self.rng, generator_address(self.rng))
        return cached[1]

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
