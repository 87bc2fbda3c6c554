"""The race of arms in one run of the robust loop: when an arm joins, which arms' samples pool
toward the stop, and when an arm is dropped (docs/design.md, "the race of line pairs").

The loop (``robust.loop``) draws and scores; it asks the race which arms are active, how many of
their samples count toward the stop (:meth:`Race.pooled_samples`) and how many an arm with a
share may still draw (:meth:`Race.share_left`), and after each round lets it drop lagging arms
and add the next one (:meth:`Race.step`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator

import numpy as np

from sepfm_ros.geometry.robust.contract import Problem
from sepfm_ros.geometry.robust.options import RaceOptions
from sepfm_ros.geometry.robust.state import Arm, Best, Budget
from sepfm_ros.geometry.robust.trials import trials_needed

__all__ = ["Race"]


class Race:
    """The race policy of one run.

    Args:
        source: the problems, pulled one by one as they join (a lazy iterator may build each
            only then).
        options: the schedule, drop and pooling rules.
        arms, best, budget: the run's state, shared with the loop (read here; ``arms`` also
            grows through ``join``).
        needed: samples arm ``a`` needs to stop at the best model's inlier ratio (the loop's
            stopping rule).
        confidence, max_samples: the run's confidence and sample cap.
    """

    def __init__(
        self,
        source: Iterator[Problem],
        options: RaceOptions,
        arms: list[Arm],
        best: Best,
        budget: Budget,
        needed: Callable[[int], int],
        confidence: float,
        max_samples: int,
    ) -> None:
        self.source, self.options = source, options
        self.arms, self.best, self.budget, self.needed = arms, best, budget, needed
        self.confidence, self.max_samples = confidence, max_samples
        self.active: list[int] = []  #: indices of the arms still sampling
        self.dropped: list[int] = []  #: indices of the arms dropped
        self.joined = 0  #: arms that joined on the schedule (after the first)
        self.next_join = options.add_after[0] if options.add_after else max_samples
        self._best_inliers: tuple[object, np.ndarray] | None = None  # (best model, inliers)

    def next_problem(self) -> Problem | None:
        """The next problem of the source, None when there is none."""
        return next(self.source, None)

    def total(self) -> int:
        """Samples drawn by all arms."""
        return sum(arm.samples for arm in self.arms)

    def agrees(self, a: int) -> bool:
        """Arm ``a`` holds the best model or its best support is near the best model's."""
        best = self.best
        return a == best.leader or self.arms[a].best_count >= self.options.drop_ratio * best.count

    def consistent(self, a: int) -> bool:
        """Arm ``a``'s fixed points are inliers of the best model (its problem's
        ``fixed_inliers``; True before any model). Cached per best model."""
        arm, model = self.arms[a], self.best.model
        if model is None:
            return True
        if arm.consistent is None or arm.consistent[0] is not model:
            arm.consistent = (model, arm.problem.fixed_inliers(model))
        return arm.consistent[1]

    def pools(self, a: int) -> bool:
        """Arm ``a``'s samples count toward the stop (``pool_rule``, ``pool_ratio``); never those
        of an arm whose fixed points are outliers of the best model."""
        arm, best, opt = self.arms[a], self.best, self.options
        if not self.consistent(a):
            return False
        if a == best.leader:
            return True
        if opt.pool_rule != "model":
            return arm.best_count >= opt.pool_ratio * best.count
        if arm.top_model is None:
            return False
        if self._best_inliers is None or self._best_inliers[0] is not best.model:
            self._best_inliers = (best.model, arm.problem.inliers(best.model))
        ov = arm.overlap
        if ov is None or ov[0] is not arm.top_model or ov[1] is not best.model:
            mask = self._best_inliers[1]
            own = arm.problem.inliers(arm.top_model)
            share = float(np.count_nonzero(mask & own)) / max(1, int(np.count_nonzero(mask)))
            arm.overlap = ov = (arm.top_model, best.model, share)
        return ov[2] >= opt.pool_ratio

    def pooled_samples(self, a: int) -> float:
        """Samples drawn by the arms that pool with the best model, in samples of arm ``a``
        (0 before there is one): an arm b whose samples are all-inlier at another rate counts
        n_b F(k_a, r) / F(k_b, r), so the pooled stop is the chance that none of the pooled
        arms drew an all-inlier sample, prod_b (1 - w_b)^n_b <= 1 - p."""
        if self.best.leader < 0:
            return 0.0
        need = self.needed(a)
        done = 0.0
        for b, arm in enumerate(self.arms):
            if arm.samples and self.pools(b):
                nb = self.needed(b)
                done += arm.samples if nb == need else arm.samples * need / nb
        return done

    def share_left(self, a: int) -> int:
        """Samples arm ``a`` may still draw under its share of all samples (no limit for arms
        without one, or when no arm without a share is active)."""
        arm = self.arms[a]
        if arm.share >= 1.0 or all(self.arms[c].share < 1.0 for c in self.active):
            return self.max_samples
        others = self.total() - arm.samples
        return int(arm.share / (1.0 - arm.share) * others) - arm.samples

    def drop_after(self, a: int) -> float:
        """Samples after which a lagging arm ``a`` is dropped: had its fixed points been right,
        it would have drawn an all-inlier sample by then with probability 1 - drop_alpha (at
        the best model's inlier ratio)."""
        p = self.arms[a].problem
        w = min(1.0, max(self.best.count, 0) / p.n)
        p_good = w**p.sample_size
        # the C library's logarithm, as in the compiled loop (numpy's may differ in the last bit)
        return math.log(self.options.drop_alpha) / math.log(max(1e-300, 1.0 - p_good))

    def unfixed_affordable(self, a: int) -> bool:
        """F(p, r) samples of p points (arm ``a``'s problem's ``free_sample_size``) fit in what
        is left of the budget at the best model's inlier ratio."""
        p = self.arms[a].problem
        count = max(self.best.count, 0)
        need = trials_needed(p.free_sample_size(), count, p.n, self.confidence, self.max_samples)
        return need <= self.budget.left()

    def drop_lagging(self, optimize: Callable[[int], None]) -> None:
        """Drop arms whose support lags (after one local optimisation of their best model,
        ``optimize(a)``, since a minimal sample with fixed line points is often badly
        conditioned), and arms whose fixed points are outliers of the best model (none of their
        samples can be all-inlier for it; the leader's included: the next arm or the caller's
        fallback goes on). Such an arm is dropped at once when a sample without fixed points
        could still find the best model's consensus in what is left of the budget; at lower
        inlier ratios the best model may be a chance one that the arm's own samples can still
        beat, and it is dropped only after the F(k, r) samples that would have stopped the
        run."""
        if self.best.count <= 0:
            return
        for a in list(self.active):
            if not self.consistent(a) and (
                self.arms[a].samples >= self.needed(a) or self.unfixed_affordable(a)
            ):
                self.drop(a)
        if len(self.arms) <= 1:
            return
        for a in list(self.active):
            arm = self.arms[a]
            if self.agrees(a) or arm.samples < self.drop_after(a):
                continue
            if not arm.checked and arm.model is not None:
                arm.checked = True
                optimize(a)
                if self.agrees(a):
                    continue
            self.drop(a)

    def drop(self, a: int) -> None:
        """Arm ``a`` stops sampling."""
        self.active.remove(a)
        self.dropped.append(a)

    def join_on_schedule(self, join: Callable[[], bool]) -> None:
        """Let the next arm join (``join()``: False when there is none) when the schedule says
        so or no arm is active."""
        if self.total() < self.next_join and self.active:
            return
        if not join():
            self.next_join = self.max_samples + 1
            return
        self.joined += 1
        add_after = self.options.add_after
        if self.joined < len(add_after):
            self.next_join = add_after[self.joined]
        else:
            self.next_join = int(np.ceil(self.next_join * self.options.add_growth))

    def step(self, optimize: Callable[[int], None], join: Callable[[], bool]) -> None:
        """After a round: drop lagging arms, then let the next one join on schedule."""
        self.drop_lagging(optimize)
        self.join_on_schedule(join)
