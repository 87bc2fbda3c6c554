"""The robust loop: LO-RANSAC with the adaptive stop F(k, r), over one or more racing arms.

One round of :meth:`Loop.run`: every active arm draws a batch of samples (:meth:`Loop.sample_arm`),
solves and scores them through its :class:`~sepfm_ros.geometry.robust.contract.Problem`, offers
the models (:meth:`Loop.offer`: the lowest cost is the best model) and optimises the promising
ones locally; the loop stops when the arms that agree with the best model drew F(k, r) samples
together (:meth:`Loop.converged`), or when the budget is spent; otherwise the race
(:class:`~sepfm_ros.geometry.robust.race.Race`) drops lagging arms and lets the next one join.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sepfm_ros.geometry.robust.contract import Problem
from sepfm_ros.geometry.robust.options import RaceOptions, SamplingOptions
from sepfm_ros.geometry.robust.race import Race
from sepfm_ros.geometry.robust.samplers import ProsacSampler, draw_samples
from sepfm_ros.geometry.robust.sprt import Sprt
from sepfm_ros.geometry.robust.state import Arm, Best, Budget
from sepfm_ros.geometry.robust.stopping import StoppingRule

__all__ = ["Budget", "Loop", "RansacResult", "make_loop", "run_ransac"]


@dataclass
class RansacResult:
    """What one run found."""

    model: Any
    cost: float
    count: int
    leader: int  #: index of the arm that produced the model (-1 when none)
    hypotheses: int  #: models scored (minimal-sample models and local-optimisation models)
    samples: list[int] = field(default_factory=list)  #: samples drawn per arm
    dropped: list[int] = field(default_factory=list)  #: arms dropped: lagging, or fixed points out
    converged: bool = False  #: adaptive stopping reached (False: stopped at max_samples)
    points_read: int = 0  #: points verified for minimal-sample models (SPRT / bail-out only)
    rejected: int = 0  #: minimal-sample models rejected by the SPRT


class Loop:
    """One run of the robust loop (arguments: those of :func:`run_ransac`)."""

    def __init__(
        self,
        arms: Iterable[Problem],
        rng: np.random.Generator,
        confidence: float,
        max_samples: int,
        min_samples: int,
        race: RaceOptions,
        batch: int,
        extra_lo_ratio: float,
        max_extra_lo: int,
        budget: Budget,
        sampling: SamplingOptions,
    ) -> None:
        self.rng, self.batch, self.budget, self.sampling = rng, batch, budget, sampling
        self.max_samples = max_samples
        self.extra_lo_ratio, self.max_extra_lo = extra_lo_ratio, max_extra_lo
        self.stopping = StoppingRule(confidence, max_samples, min_samples)
        self.sprt: Sprt | None = None  # made when the first arm joins (it knows n)
        self.arms: list[Arm] = []
        self.best = Best()
        self.race = Race(
            iter(arms), race, self.arms, self.best, budget, self.needed, confidence, max_samples
        )
        self.extra_lo = 0  #: local optimisations of models that did not beat their arm's best
        self.hypotheses = 0  #: models scored
        self.local_optimizing = True  #: False during a probe (:meth:`start`)

    def join(self) -> bool:
        """Add the race's next problem as an arm; False when there is none."""
        problem = self.race.next_problem()
        if problem is None:
            return False
        arm = Arm(problem, share=float(problem.race_share))
        opt = self.sampling
        if opt.prosac:
            growth = opt.prosac_growth or self.max_samples
            arm.sampler = ProsacSampler(problem.pool, problem.sample_size, growth)
        if (opt.sprt or opt.bailout) and self.sprt is None:
            self.sprt = Sprt(opt, problem.n)
        self.arms.append(arm)
        self.race.active.append(len(self.arms) - 1)
        return True

    def start_from(self, model: Any, cost: float, count: int) -> None:
        """Take ``model`` (from an earlier run) as arm 0's and the best model so far."""
        self.best.model, self.best.cost, self.best.count = model, cost, count
        self.best.leader = 0
        if self.sprt is not None:
            self.sprt.update(count, self.arms[0].problem.n)

    def needed(self, a: int) -> int:
        """Samples of arm ``a`` needed to stop at the best model's inlier ratio."""
        p = self.arms[a].problem
        A = np.inf if self.sprt is None else self.sprt.A
        return self.stopping.needed(p.sample_size, p.n, self.best.count, A)

    def converged(self) -> bool:
        """The arms that agree with the best model drew F(k, r) samples together."""
        lead = self.best.leader
        return lead >= 0 and self.race.pooled_samples(lead) >= self.needed(lead)

    def offer(self, a: int, models: Any, cost: np.ndarray, count: np.ndarray) -> int:
        """Record scored models of arm ``a``; index of the cheapest; updates the best model."""
        self.hypotheses += len(models)
        i = int(np.argmin(cost))
        arm, best = self.arms[a], self.best
        relative = arm.problem.relative_counts
        if not relative:
            arm.best_count = max(arm.best_count, int(count.max()))
        if cost[i] < arm.top_cost:
            arm.top_model, arm.top_cost = models[i], float(cost[i])
            if relative:
                arm.best_count = int(count[i])
        if cost[i] < best.cost:
            best.model, best.cost = models[i], float(cost[i])
            best.count, best.leader = int(count[i]), a
            if self.sprt is not None:
                self.sprt.update(best.count, arm.problem.n)
            if relative:  # counts are relative to the best model: re-count the others
                for b, other in enumerate(self.arms):
                    if b != a and other.top_model is not None and other.problem.relative_counts:
                        other.best_count = other.problem.recount(other.top_model)
        return i

    def local_optimization(self, a: int, model: Any, cost: float) -> None:
        """LO-RANSAC step from ``model`` (cost ``cost``) of arm ``a``: its refits are scored, and
        when the problem's ``polish`` returns models (the ``"lm"`` scheme), the polish of the
        best of ``model`` and its refits is offered in their place (the refits' scores only
        choose its start)."""
        problem = self.arms[a].problem
        lo = problem.local_optimize(model)
        scored = problem.score(lo) if len(lo) else None
        start = model
        if scored is not None and scored[0].min() < cost:
            start = lo[int(np.argmin(scored[0]))]
        refined = problem.polish(model, start)
        if len(refined):
            self.offer(a, refined, *problem.score(refined))
        elif scored is not None:
            self.offer(a, lo, *scored)

    def optimize_best(self, a: int) -> None:
        """Local optimisation of arm ``a``'s best minimal-sample model (the race's check
        before it drops a lagging arm)."""
        arm = self.arms[a]
        self.local_optimization(a, arm.model, arm.cost)

    def sample_round(self) -> None:
        """Every active arm draws and scores one batch, sized by what is still needed and by the
        most-sampled arm, so an arm that joins late races at the leader's pace (why: the race of
        line pairs in docs/design.md)."""
        race = self.race
        pace = max(1, max(self.arms[a].samples for a in race.active))
        for a in list(race.active):
            need = self.needed(a)
            done = race.pooled_samples(a)
            if self.best.leader >= 0 and done >= need:
                break
            # batches grow 1, 1, 2, 4, ... so the sequential stopping rule is barely overshot
            b = max(1, min(int(np.ceil(need - done)), self.batch, pace))
            b = min(b, self.budget.left(), race.share_left(a))
            if b > 0:
                self.sample_arm(a, b)

    def sample_arm(self, a: int, b: int) -> None:
        """Draw, solve and score ``b`` samples of arm ``a``, then optimise locally.

        LO-RANSAC runs on every minimal-sample model that beats its own arm's best
        minimal-sample model so far (not the best refined model, nor other arms' models: with
        fixed line points minimal samples are badly conditioned; see docs/design.md), and on up
        to ``max_extra_lo`` models close to it.
        """
        arm = self.arms[a]
        if arm.sampler is not None:
            smp = arm.sampler.draw(self.rng, b)
        else:
            smp = draw_samples(self.rng, arm.problem.pool, arm.problem.sample_size, b)
        arm.samples += b
        self.budget.spend(b)
        models, _ = arm.problem.solve(smp)
        if self.sprt is not None:
            self.sprt.samples += b
            self.sprt.models += len(models)
        if len(models) == 0:
            return
        cost, count = self.score_minimal(a, models)
        i = self.offer(a, models, cost, count)
        if self.sprt is not None and not np.isfinite(cost[i]):  # every model rejected early
            return
        if cost[i] < arm.cost:
            arm.model, arm.cost = models[i], float(cost[i])
            arm.raw_count = int(count[i])
            if self.local_optimizing:
                self.local_optimization(a, models[i], float(cost[i]))
        elif (
            self.local_optimizing
            and self.extra_lo < self.max_extra_lo
            and count[i] >= self.extra_lo_ratio * arm.raw_count
        ):
            self.extra_lo += 1
            self.local_optimization(a, models[i], float(cost[i]))

    def score_minimal(self, a: int, models: Any) -> tuple[np.ndarray, np.ndarray]:
        """Score minimal-sample models of arm ``a``: fully, or with SPRT / bail-out when on
        (rejected models: cost inf, count of the points read)."""
        problem = self.arms[a].problem
        sprt = self.sprt
        if sprt is None:
            return problem.score(models)
        arm = self.arms[a]
        bail_cost, bail_count = np.inf, 0
        if self.sampling.bailout and np.isfinite(arm.cost):
            bail_cost = arm.cost
            bail_count = arm.best_count + 1
            if self.extra_lo < self.max_extra_lo:
                bail_count = min(bail_count, int(np.ceil(self.extra_lo_ratio * arm.raw_count)))
        cost, count, read, rejected = problem.score_early(
            models, sprt.order, *sprt.logs(), bail_cost, bail_count
        )
        sprt.points_read += int(read.sum())
        if rejected.any():
            sprt.rejected += int(rejected.sum())
            sprt.rej_inliers += int(count[rejected].sum())
            sprt.rej_read += int(read[rejected].sum())
        return cost, count

    def start(self, samples: int) -> bool:
        """The rounds of :meth:`run`, without local optimisation, until at least ``samples``
        samples are drawn in all, the stop or the budget's end (the separable method's probe of
        the inlier ratio: minimal-sample models only, so a probe that is dropped costs little);
        True when the loop converged. :meth:`resume` then lets :meth:`run` go on."""
        self.local_optimizing = False
        try:
            while self.race.active and sum(arm.samples for arm in self.arms) < samples:
                self.sample_round()
                if self.converged():
                    return True
                if self.budget.left() <= 0:
                    return False
                self.race.step(self.optimize_best, self.join)
            return self.converged()
        finally:
            self.local_optimizing = True

    def resume(self) -> None:
        """After :meth:`start`: local optimisation of each arm's best minimal-sample model (the
        step the probe left out), so :meth:`run` goes on as if it had drawn the probe's samples
        itself."""
        for a, arm in enumerate(self.arms):
            if arm.model is not None:
                self.local_optimization(a, arm.model, arm.cost)

    def run(self) -> RansacResult:
        """Rounds until the stop, the budget's end or no arm is left; the result."""
        converged = False
        while self.race.active:
            self.sample_round()
            if self.converged():
                converged = True
                break
            if self.budget.left() <= 0:
                break
            self.race.step(self.optimize_best, self.join)
        return self.result(converged)

    def result(self, converged: bool) -> RansacResult:
        """The run's result from its state (``converged``: the adaptive stop was reached)."""
        best = self.best
        return RansacResult(
            model=best.model,
            cost=best.cost,
            count=max(best.count, 0),
            leader=best.leader,
            hypotheses=self.hypotheses,
            samples=[arm.samples for arm in self.arms],
            dropped=self.race.dropped,
            converged=converged,
            points_read=self.sprt.points_read if self.sprt else 0,
            rejected=self.sprt.rejected if self.sprt else 0,
        )


def run_ransac(
    arms: Iterable[Problem],
    rng: np.random.Generator,
    confidence: float = 0.99,
    max_samples: int = 10000,
    min_samples: int = 1,
    race: RaceOptions | None = None,
    batch: int = 64,
    initial: tuple[Any, float, int] | None = None,
    extra_lo_ratio: float = 0.6,
    max_extra_lo: int = 10,
    budget: Budget | None = None,
    sampling: SamplingOptions | None = None,
    cls: type[Loop] = Loop,
) -> RansacResult:
    """Run RANSAC over one or more arms with adaptive stopping F(k, r) and local optimisation.

    Arm 0 starts; further arms are pulled from ``arms`` (lazily: an iterator may build each arm
    only when it joins) on the ``race`` schedule and are dropped when their support lags (see
    :class:`RaceOptions`). The loop stops when the arms that pool with the best model have
    drawn F(k, r) samples together for the inlier ratio of the best model, or when
    ``max_samples`` samples were drawn in all. An arm pools when it holds the best model or
    passes ``race.pool_rule`` (by default: its own best support is at least ``race.pool_ratio``
    of the best model's): arms whose fixed points are all inliers draw an all-inlier sample at
    the same rate w^k, so their samples pool (several good line pairs racing would otherwise
    each draw F(k, r) samples); a lagging arm's do not count. An arm of another sample size k'
    counts each of its samples as F(k, r) / F(k', r) of the leader's (a seven-point sample is
    worth far less than a four-point one with three fixed inliers).

    Args:
        arms: problems to sample (a list or a lazy iterator); all score against the same data.
        rng: the random generator (seeded by the caller).
        confidence: RANSAC confidence p.
        max_samples: cap on the total number of samples over all arms.
        min_samples: samples drawn at least (by the agreeing arms together) before stopping.
        race: racing options (only used with more than one arm).
        batch: most samples one arm solves and scores in one vectorised call.
        initial: optional (model, cost, count) from an earlier run to start from; it counts as
            arm 0's model.
        extra_lo_ratio, max_extra_lo: up to ``max_extra_lo`` further local optimisations of
            models whose support reaches ``extra_lo_ratio`` of their arm's best raw support.
        budget: a :class:`Budget` shared with other stages of the same estimate; the loop stops
            when it is spent (default: a fresh budget of ``max_samples``). ``max_samples`` still
            caps F(k, r).
        sampling: PROSAC / SPRT / bail-out (:class:`SamplingOptions`; default all off).
        cls: the :class:`Loop` class that runs the rounds (a subclass may run them compiled).

    With PROSAC the stopping rule stays F(k, r) over all samples drawn, as for uniform
    sampling: it is exact once the schedule has reached the whole pool, and before that it is
    conservative as long as the top of the pool is at least as clean as the whole (the point
    of ordering by quality); the schedule's T_N defaults to ``max_samples``, so a run that does
    not converge has just grown to the whole pool when it stops. With the SPRT the all-inlier
    probability of F(k, r) is scaled by 1 - 1/A, the chance that the SPRT accepts a good model.
    """
    return make_loop(
        arms, rng, confidence, max_samples, min_samples, race, batch, initial, extra_lo_ratio,
        max_extra_lo, budget, sampling, cls,
    ).run()  # fmt: skip


def make_loop(
    arms: Iterable[Problem],
    rng: np.random.Generator,
    confidence: float = 0.99,
    max_samples: int = 10000,
    min_samples: int = 1,
    race: RaceOptions | None = None,
    batch: int = 64,
    initial: tuple[Any, float, int] | None = None,
    extra_lo_ratio: float = 0.6,
    max_extra_lo: int = 10,
    budget: Budget | None = None,
    sampling: SamplingOptions | None = None,
    cls: type[Loop] = Loop,
) -> Loop:
    """The :class:`Loop` that :func:`run_ransac` runs (same arguments), with its first arm
    joined, before any sample: ``make_loop(...).run()`` is ``run_ransac(...)``. ``cls``: a
    subclass that runs the same rounds another way (e.g. compiled)."""
    loop = cls(
        arms, rng, confidence, max_samples, min_samples, race or RaceOptions(), batch,
        extra_lo_ratio, max_extra_lo, budget or Budget(max_samples), sampling or SamplingOptions(),
    )  # fmt: skip
    loop.join()
    if initial is not None and loop.arms:
        loop.start_from(*initial)
    return loop
