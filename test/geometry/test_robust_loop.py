"""The robust loop alone, on stub problems (no fundamental matrix): the stopping rule exactly, and
the race policy (pooling, shares, drops, the join schedule) on hand-made arm states."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sepfm_ros.geometry.robust.contract import Problem
from sepfm_ros.geometry.robust.loop import run_ransac
from sepfm_ros.geometry.robust.options import RaceOptions
from sepfm_ros.geometry.robust.race import Race
from sepfm_ros.geometry.robust.state import Arm, Best, Budget
from sepfm_ros.geometry.robust.stopping import StoppingRule


def f_k_r(k: int, inliers: int, n: int, p: float) -> int:
    """The paper's F(k, r) with r = 1 - inliers / n, written out here (not the project's)."""
    w = (inliers / n) ** k
    return max(1, math.ceil(math.log(1 - p) / math.log(1 - w)))


class StubProblem(Problem):
    """n points, the first ``good`` of them inliers. A sample's model is 1.0 when every point of
    the sample is an inlier (it then has ``good`` inliers) and 0.0 otherwise (``weak`` inliers).
    Records the samples drawn when the first all-inlier sample was solved."""

    def __init__(self, n: int, good: int, k: int, weak: int | None = None) -> None:
        self.n, self.sample_size, self.good = n, k, good
        self.weak = good if weak is None else weak
        self.pool = np.arange(n)
        self.drawn = 0
        self.first_good_at: int | None = None  # samples drawn by the end of that batch

    def solve(self, samples: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        self.drawn += len(samples)
        models = np.all(samples < self.good, axis=1).astype(float)
        if self.first_good_at is None and models.any():
            self.first_good_at = self.drawn
        return models[:, None], np.arange(len(samples))

    def counts(self, models: np.ndarray) -> np.ndarray:
        return np.where(models[:, 0] > 0, self.good, self.weak)

    def score(self, models: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        count = self.counts(models)
        return (self.n - count).astype(float), count

    def inliers(self, model: np.ndarray) -> np.ndarray:
        return np.arange(self.n) < (self.good if model[0] > 0 else self.weak)


@pytest.mark.parametrize(
    "k, good, n, p", [(4, 50, 100, 0.99), (7, 80, 100, 0.99), (4, 60, 200, 0.95), (3, 9, 10, 0.999)]
)
def test_the_loop_stops_exactly_at_f_k_r_of_the_best_inlier_ratio(k, good, n, p):
    # every model has `good` inliers: the stop is F(k, r) from the first sample on, and the
    # batches (1, 1, 2, 4, ... capped at what is still needed) end exactly there
    problem = StubProblem(n, good, k)
    result = run_ransac([problem], np.random.default_rng(0), p, max_samples=5000)
    assert result.converged
    assert result.samples == [f_k_r(k, good, n, p)] == [problem.drawn]
    assert result.count == good and result.leader == 0


@pytest.mark.parametrize("seed", range(5))
def test_the_stop_follows_the_best_model_found(seed):
    # weak models (10 of 100) until the first all-inlier sample (60 of 100): the loop stops at
    # F(4, 0.4) samples, or at the end of the batch that found the good model if later
    problem = StubProblem(100, 60, 4, weak=10)
    result = run_ransac([problem], np.random.default_rng(seed), 0.99, max_samples=5000)
    assert result.converged and result.count == 60
    assert problem.first_good_at is not None
    assert result.samples[0] == max(f_k_r(4, 60, 100, 0.99), problem.first_good_at)


def test_min_samples_and_the_cap_bound_the_stop():
    need = f_k_r(4, 90, 100, 0.99)
    more = run_ransac([StubProblem(100, 90, 4)], np.random.default_rng(0), 0.99, 1000, need + 17)
    assert more.samples == [need + 17] and more.converged
    capped = run_ransac([StubProblem(100, 5, 4)], np.random.default_rng(0), 0.99, max_samples=50)
    assert capped.samples == [50]


def test_the_stopping_rule_alone():
    rule = StoppingRule(0.99, 10_000, 3)
    assert rule.needed(4, 100, 50) == f_k_r(4, 50, 100, 0.99)
    assert rule.needed(4, 100, 100) == 3  # one sample is enough, the floor is 3
    assert rule.needed(4, 100, -1) == 10_000  # no model yet: the cap
    # the SPRT accepts a good model with probability 1 - 1/A: F(1, 1 - w^k (1 - 1/A))
    A = 20.0
    w = 0.5**4 * (1 - 1 / A)
    assert rule.needed(4, 100, 50, A) == math.ceil(math.log(0.01) / math.log(1 - w))


def _race(arms: list[Arm], best: Best, options: RaceOptions | None = None, left: int = 10**6):
    """A race over given arm states; needed(a) is F(k, r) of arm a at the best count."""

    def needed(a: int) -> int:
        p = arms[a].problem
        return f_k_r(p.sample_size, max(best.count, 1), p.n, 0.99)

    race = Race(iter(()), options or RaceOptions(), arms, best, Budget(left), needed, 0.99, 10**6)
    race.active = list(range(len(arms)))
    return race


class FixedStub(StubProblem):
    """A stub whose fixed points are outliers of every model (``fixed_inliers`` False)."""

    def fixed_inliers(self, model: np.ndarray) -> bool:
        return False


def test_pooled_samples_count_agreeing_arms_at_their_own_rate():
    best = Best(model=np.array([1.0]), cost=40.0, count=60, leader=0)
    arms = [
        Arm(StubProblem(100, 60, 4), samples=10, best_count=60),
        Arm(StubProblem(100, 60, 4), samples=7, best_count=50),  # 50 >= 0.8 * 60: pools
        Arm(StubProblem(100, 60, 4), samples=5, best_count=40),  # lags: does not pool
        Arm(StubProblem(100, 60, 7), samples=30, best_count=55),  # k = 7: pools at its rate
        Arm(FixedStub(100, 60, 4), samples=9, best_count=60),  # fixed points out: never
    ]
    race = _race(arms, best)
    assert [race.pools(a) for a in range(5)] == [True, True, False, True, False]
    rate = f_k_r(4, 60, 100, 0.99) / f_k_r(7, 60, 100, 0.99)
    assert race.pooled_samples(0) == pytest.approx(10 + 7 + 30 * rate)


def test_pool_rule_model_compares_inlier_sets():
    best = Best(model=np.array([1.0]), cost=40.0, count=60, leader=0)
    weak = StubProblem(100, 60, 4, weak=50)  # its models' inliers: the first 50 of the 60
    arms = [Arm(StubProblem(100, 60, 4), samples=10, best_count=60)]
    arms.append(Arm(weak, samples=10, best_count=10, top_model=np.array([0.0])))
    assert _race(arms, best, RaceOptions(pool_rule="model", pool_ratio=0.8)).pools(1)  # 50/60
    assert not _race(arms, best, RaceOptions(pool_rule="model", pool_ratio=0.9)).pools(1)
    assert not _race(arms, best, RaceOptions(pool_rule="support")).pools(1)  # 10 < 48


def test_a_share_limits_an_arm_while_an_arm_without_one_is_active():
    best = Best()
    arms = [Arm(StubProblem(100, 60, 4), samples=300), Arm(StubProblem(100, 60, 7), share=0.25)]
    arms[1].samples = 40
    race = _race(arms, best)
    assert race.share_left(1) == int(0.25 / 0.75 * 300) - 40  # 60 more
    assert race.share_left(0) == 10**6
    race.active = [1]  # alone: no limit
    assert race.share_left(1) == 10**6


def test_drops_an_arm_whose_fixed_points_are_out_and_a_lagging_one():
    best = Best(model=np.array([1.0]), cost=40.0, count=60, leader=0)
    arms = [
        Arm(StubProblem(100, 60, 4), samples=50, best_count=60),
        Arm(FixedStub(100, 60, 4), samples=1, best_count=60),  # out at once: F(4, r) affordable
        Arm(StubProblem(100, 60, 4), samples=200, best_count=20, model=np.array([0.0])),
    ]
    optimized = []
    race = _race(arms, best)
    race.drop_lagging(optimized.append)
    # arm 2 lags after drop_after samples; it is optimised once before it is dropped
    assert race.drop_after(2) < 200
    assert optimized == [2] and race.dropped == [1, 2] and race.active == [0]


def test_fixed_points_out_wait_for_f_k_r_when_the_budget_is_short():
    best = Best(model=np.array([1.0]), cost=40.0, count=60, leader=0)
    arms = [Arm(FixedStub(100, 60, 4), samples=3, best_count=60)]
    race = _race(arms, best, left=5)  # F(4, 0.4) = 34 samples do not fit in 5
    race.drop_lagging(lambda a: None)
    assert race.active == [0]
    arms[0].samples = f_k_r(4, 60, 100, 0.99)
    race.drop_lagging(lambda a: None)
    assert race.dropped == [0]


def test_join_schedule():
    joins = []
    arms = [Arm(StubProblem(100, 60, 4), samples=10)]
    race = _race(arms, Best(), RaceOptions(add_after=(40, 100), add_growth=2.0))

    def join() -> bool:
        joins.append(race.total())
        return len(joins) < 4

    for total in (10, 39, 40, 99, 100, 199, 200, 399, 400):
        arms[0].samples = total
        race.join_on_schedule(join)
    # joins at 40 and 100 (the list), then at 200 (100 x 2); the fourth finds no arm left
    assert joins == [40, 100, 200, 400]
    assert race.next_join == 10**6 + 1
