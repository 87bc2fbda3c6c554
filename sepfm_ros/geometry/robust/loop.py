"""The robust loop (LO-RANSAC with adaptive stopping F(k, r)) over one or more racing arms.

Each arm is a :class:`~sepfm_ros.geometry.robust.contract.Problem`; several arms can race in one
loop, which is how the separable estimator tries several line pairs and drops the ones whose
support lags.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sepfm_ros.geometry.robust.contract import Problem
from sepfm_ros.geometry.robust.options import RaceOptions, SamplingOptions
from sepfm_ros.geometry.robust.samplers import ProsacSampler, draw_samples
from sepfm_ros.geometry.robust.sprt import Sprt
from sepfm_ros.geometry.robust.trials import trial_count, trials_needed

__all__ = ["Budget", "RansacResult", "run_ransac"]


@dataclass
class Budget:
    """Samples one estimate may draw, shared by every stage that draws them (the separable
    method's stage 1 and stage 2, and its fallback), so no method gets more than ``limit``.

    Attributes:
        limit: samples allowed in all (minimal samples of every stage).
        used: samples drawn so far.
    """

    limit: int
    used: int = 0

    def left(self) -> int:
        """Samples still allowed (>= 0)."""
        return max(0, self.limit - self.used)

    def spend(self, n: int) -> None:
        """Record ``n`` samples drawn."""
        self.used += int(n)


@dataclass
class RansacResult:
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


@dataclass
class _Arm:
    """Book-keeping of one arm during :func:`run_ransac`."""

    problem: Problem
    samples: int = 0  #: samples drawn
    best_count: int = -1  #: best inlier count of any of its models (minimal or refined)
    model: Any = None  #: best minimal-sample model, and its cost and inlier count
    cost: float = np.inf
    raw_count: int = 0
    checked: bool = False  #: its best model was locally optimised before a drop
    sampler: ProsacSampler | None = None  #: PROSAC state (None: uniform sampling)
    top_model: Any = None  #: lowest-cost model of any kind (minimal or refined)
    top_cost: float = np.inf
    overlap: tuple[Any, Any, float] | None = None  #: (its model, best model, share) for "model"
    consistent: tuple[Any, bool] | None = None  #: (best model, its fixed points are inliers)
    share: float = 1.0  #: most of all samples it may draw (its problem's ``race_share``)


class _Run:
    """State of one :func:`run_ransac` call; each method is one step of the loop."""

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
        self.source = iter(arms)
        self.sampling = sampling
        self.sprt: Sprt | None = None  # made when the first arm joins (it knows n)
        self.rng, self.confidence, self.race, self.batch = rng, confidence, race, batch
        self.max_samples, self.min_samples = max_samples, min_samples
        self.budget = budget
        self.extra_lo_ratio, self.max_extra_lo = extra_lo_ratio, max_extra_lo
        self.arms: list[_Arm] = []
        self.active: list[int] = []
        self.dropped: list[int] = []
        self.best_model: Any = None
        self.best_cost = np.inf
        self.best_count = -1
        self.leader = -1
        self._best_inliers: tuple[Any, np.ndarray] | None = None  # (best model, its inliers)
        self.extra_lo = 0
        self._needed: dict[tuple, int] = {}  # memo of needed()
        self.hypotheses = 0
        self.total = 0
        self.n_join = 0
        self.next_join = race.add_after[0] if race.add_after else max_samples

    def join(self) -> bool:
        """Pull the next arm from the source; False when there is none."""
        problem = next(self.source, None)
        if problem is None:
            return False
        arm = _Arm(problem)
        arm.share = float(getattr(problem, "race_share", 1.0))
        opt = self.sampling
        if opt.prosac:
            growth = opt.prosac_growth or self.max_samples
            arm.sampler = ProsacSampler(problem.pool, problem.sample_size, growth)
        if (opt.sprt or opt.bailout) and self.sprt is None:
            self.sprt = Sprt(opt, problem.n)
        self.arms.append(arm)
        self.active.append(len(self.arms) - 1)
        return True

    def offer(self, a: int, models: Any, cost: np.ndarray, count: np.ndarray) -> int:
        """Record scored models of arm ``a``; index of the cheapest; updates the best model."""
        self.hypotheses += len(models)
        i = int(np.argmin(cost))
        arm = self.arms[a]
        recount = getattr(arm.problem, "recount", None)
        if recount is None:
            arm.best_count = max(arm.best_count, int(count.max()))
        if cost[i] < arm.top_cost:
            arm.top_model, arm.top_cost = models[i], float(cost[i])
            if recount is not None:
                arm.best_count = int(count[i])
        if cost[i] < self.best_cost:
            self.best_model, self.best_cost = models[i], float(cost[i])
            self.best_count, self.leader = int(count[i]), a
            if self.sprt is not None:
                self.sprt.update(self.best_count, arm.problem.n)
            if recount is not None:  # counts are relative to the best model: re-count the others
                for b, other in enumerate(self.arms):
                    if b != a and other.top_model is not None and hasattr(other.problem, "recount"):
                        other.best_count = other.problem.recount(other.top_model)
        return i

    def local_optimization(self, a: int, model: Any, cost: float) -> None:
        """LO-RANSAC step from ``model`` (cost ``cost``) of arm ``a``: its refits are scored, and
        for problems with a ``polish`` step that returns models (the ``"lm"`` scheme), the
        polish of the best of ``model`` and its refits is offered in their place (the refits'
        scores only choose its start)."""
        problem = self.arms[a].problem
        lo = problem.local_optimize(model)
        scored = problem.score(lo) if len(lo) else None
        polish = getattr(problem, "polish", None)
        if polish is not None:
            start = model
            if scored is not None and scored[0].min() < cost:
                start = lo[int(np.argmin(scored[0]))]
            refined = polish(model, start)
            if len(refined):
                self.offer(a, refined, *problem.score(refined))
                return
        if scored is not None:
            self.offer(a, lo, *scored)

    def agrees(self, a: int) -> bool:
        """Arm ``a`` holds the best model or its best support is near the best model's."""
        return a == self.leader or self.arms[a].best_count >= self.race.drop_ratio * self.best_count

    def consistent(self, a: int) -> bool:
        """Arm ``a``'s fixed points are inliers of the best model (its problem's
        ``fixed_inliers``; True for problems without fixed points or before any model)."""
        arm = self.arms[a]
        check = getattr(arm.problem, "fixed_inliers", None)
        if check is None or self.best_model is None:
            return True
        if arm.consistent is None or arm.consistent[0] is not self.best_model:
            arm.consistent = (self.best_model, check(self.best_model))
        return arm.consistent[1]

    def pools(self, a: int) -> bool:
        """Arm ``a``'s samples count toward the stop (``race.pool_rule``, ``race.pool_ratio``);
        never those of an arm whose fixed points are outliers of the best model."""
        arm = self.arms[a]
        if not self.consistent(a):
            return False
        if a == self.leader:
            return True
        inliers = getattr(arm.problem, "inliers", None)
        if self.race.pool_rule != "model" or inliers is None:
            return arm.best_count >= self.race.pool_ratio * self.best_count
        if arm.top_model is None:
            return False
        if self._best_inliers is None or self._best_inliers[0] is not self.best_model:
            self._best_inliers = (self.best_model, inliers(self.best_model))
        ov = arm.overlap
        if ov is None or ov[0] is not arm.top_model or ov[1] is not self.best_model:
            best = self._best_inliers[1]
            share = np.count_nonzero(best & inliers(arm.top_model)) / max(1, np.count_nonzero(best))
            arm.overlap = (arm.top_model, self.best_model, share)
        return arm.overlap[2] >= self.race.pool_ratio

    def pooled_samples(self, a: int) -> float:
        """Samples drawn by the arms that pool with the best model, in samples of arm ``a``
        (0 before there is one): an arm b whose samples are all-inlier at another rate counts
        n_b F(k_a, r) / F(k_b, r), so the pooled stop is the chance that none of the pooled
        arms drew an all-inlier sample, prod_b (1 - w_b)^n_b <= 1 - p."""
        if self.leader < 0:
            return 0.0
        need = self.needed(a)
        done = 0.0
        for b, arm in enumerate(self.arms):
            if arm.samples and self.pools(b):
                nb = self.needed(b)
                done += arm.samples if nb == need else arm.samples * need / nb
        return done

    def needed(self, a: int) -> int:
        """F(k, r) of arm ``a`` at the best model's inlier ratio, at least ``min_samples``
        (memoised: it only changes with the best count and the SPRT's A)."""
        p = self.arms[a].problem
        key = (p.sample_size, p.n, self.best_count, None if self.sprt is None else self.sprt.A)
        need = self._needed.get(key)
        if need is None:
            need = self._needed[key] = self._needed_now(p)
        return need

    def _needed_now(self, p: Problem) -> int:
        count = max(self.best_count, 0)
        if self.sprt is not None and np.isfinite(self.sprt.A) and p.n > 0:
            # SPRT rejects a good model with probability <= 1 / A: an all-inlier sample
            # yields an accepted model with probability w^k (1 - 1/A) (Matas & Chum, eq. 3)
            w = min(1.0, count / p.n) ** p.sample_size * (1.0 - 1.0 / self.sprt.A)
            need = int(min(trial_count(1, w, self.confidence), float(self.max_samples)))
        else:
            need = trials_needed(p.sample_size, count, p.n, self.confidence, self.max_samples)
        return max(need, self.min_samples)

    def drop_after(self, a: int) -> float:
        """Samples after which a lagging arm ``a`` is dropped: had its fixed points been
        right, it would have drawn an all-inlier sample by then with probability
        1 - drop_alpha (at the best model's inlier ratio)."""
        p = self.arms[a].problem
        w = min(1.0, max(self.best_count, 0) / p.n)
        p_good = w**p.sample_size
        return float(np.log(self.race.drop_alpha) / np.log(max(1e-300, 1.0 - p_good)))

    def sample_round(self) -> None:
        """Every active arm draws and scores one batch, sized by what is still needed and by the
        most-sampled arm, so an arm that joins late races at the leader's pace (why: the race of
        line pairs in docs/design.md)."""
        pace = max(1, max(self.arms[a].samples for a in self.active))
        for a in list(self.active):
            need = self.needed(a)
            done = self.pooled_samples(a)
            if self.leader >= 0 and done >= need:
                break
            # batches grow 1, 1, 2, 4, ... so the sequential stopping rule is barely overshot
            b = max(1, min(int(np.ceil(need - done)), self.batch, pace))
            b = min(b, self.budget.left(), self.share_left(a))
            if b > 0:
                self.sample_arm(a, b)

    def share_left(self, a: int) -> int:
        """Samples arm ``a`` may still draw under its ``share`` of all samples (no limit for
        arms without one, or when no arm without a share is active)."""
        arm = self.arms[a]
        if arm.share >= 1.0 or all(self.arms[c].share < 1.0 for c in self.active):
            return self.max_samples
        others = self.total - arm.samples
        return int(arm.share / (1.0 - arm.share) * others) - arm.samples

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
        self.total += b
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
            self.local_optimization(a, models[i], float(cost[i]))
        elif self.extra_lo < self.max_extra_lo and count[i] >= self.extra_lo_ratio * arm.raw_count:
            self.extra_lo += 1
            self.local_optimization(a, models[i], float(cost[i]))

    def score_minimal(self, a: int, models: Any) -> tuple[np.ndarray, np.ndarray]:
        """Score minimal-sample models of arm ``a``: fully, or with SPRT / bail-out when on and
        the problem supports it (rejected models: cost inf, count of the points read)."""
        problem = self.arms[a].problem
        sprt = self.sprt
        if sprt is None or not hasattr(problem, "score_early"):
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

    def converged(self) -> bool:
        """The arms that agree with the best model drew F(k, r) samples together."""
        return self.leader >= 0 and self.pooled_samples(self.leader) >= self.needed(self.leader)

    def unfixed_affordable(self, a: int) -> bool:
        """F(p, r) samples of p points (the ``model_points`` of arm ``a``'s problem, else its
        sample size) fit in what is left of the budget at the best model's inlier ratio."""
        p = self.arms[a].problem
        k = int(getattr(p, "model_points", p.sample_size))
        need = trials_needed(k, max(self.best_count, 0), p.n, self.confidence, self.max_samples)
        return need <= self.budget.left()

    def drop_lagging(self) -> None:
        """Drop arms whose support lags (after one local optimisation of their best model, since
        a minimal sample with fixed line points is often badly conditioned), and arms whose
        fixed points are outliers of the best model (none of their samples can be all-inlier
        for it; the leader's included: the next arm or the caller's fallback goes on). Such an
        arm is dropped at once when a sample without fixed points could still find the best
        model's consensus in what is left of the budget (F(p, r) for the arm's ``model_points``
        p); at lower inlier ratios the best model may be a chance one that the arm's own
        samples can still beat, and it is dropped only after the F(k, r) samples that would
        have stopped the run."""
        if self.best_count <= 0:
            return
        for a in list(self.active):
            if not self.consistent(a) and (
                self.arms[a].samples >= self.needed(a) or self.unfixed_affordable(a)
            ):
                self.active.remove(a)
                self.dropped.append(a)
        if len(self.arms) <= 1:
            return
        for a in list(self.active):
            arm = self.arms[a]
            if self.agrees(a) or arm.samples < self.drop_after(a):
                continue
            if not arm.checked and arm.model is not None:
                arm.checked = True
                self.local_optimization(a, arm.model, arm.cost)
                if self.agrees(a):
                    continue
            self.active.remove(a)
            self.dropped.append(a)

    def join_on_schedule(self) -> None:
        """Let the next arm join when the race schedule says so or no arm is active."""
        if self.total < self.next_join and self.active:
            return
        if not self.join():
            self.next_join = self.max_samples + 1
            return
        self.n_join += 1
        add_after = self.race.add_after
        if self.n_join < len(add_after):
            self.next_join = add_after[self.n_join]
        else:
            self.next_join = int(np.ceil(self.next_join * self.race.add_growth))

    def run(self) -> RansacResult:
        converged = False
        while self.active:
            self.sample_round()
            if self.converged():
                converged = True
                break
            if self.budget.left() <= 0:
                break
            self.drop_lagging()
            self.join_on_schedule()
        return RansacResult(
            model=self.best_model,
            cost=self.best_cost,
            count=max(self.best_count, 0),
            leader=self.leader,
            hypotheses=self.hypotheses,
            samples=[arm.samples for arm in self.arms],
            dropped=self.dropped,
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

    With PROSAC the stopping rule stays F(k, r) over all samples drawn, as for uniform
    sampling: it is exact once the schedule has reached the whole pool, and before that it is
    conservative as long as the top of the pool is at least as clean as the whole (the point
    of ordering by quality); the schedule's T_N defaults to ``max_samples``, so a run that does
    not converge has just grown to the whole pool when it stops. With the SPRT the all-inlier
    probability of F(k, r) is scaled by 1 - 1/A, the chance that the SPRT accepts a good model.
    """
    run = _Run(
        arms, rng, confidence, max_samples, min_samples, race or RaceOptions(), batch,
        extra_lo_ratio, max_extra_lo, budget or Budget(max_samples), sampling or SamplingOptions(),
    )  # fmt: skip
    run.join()
    if initial is not None and run.arms:
        run.best_model, run.best_cost, run.best_count = initial
        run.leader = 0
        if run.sprt is not None:
            run.sprt.update(run.best_count, run.arms[0].problem.n)
    return run.run()
