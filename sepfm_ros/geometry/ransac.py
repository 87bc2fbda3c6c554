"""Generic RANSAC pieces: trial counts (the paper's F(k, r))."""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any, Protocol

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def trial_count(k: int, inlier_ratio: float, confidence: float) -> float:
    """The paper's F(k, r) at r = 1 - ``inlier_ratio``, uncapped (inf when no sample of k can be
    all inliers); the one implementation behind :func:`ransac_trials`, the RANSAC loop and the
    compiled stage 1.

    F(k, r) = ceil(log(1 - p) / log(1 - (1 - r)^k)), at least 1; p is ``confidence``.
    """
    w = inlier_ratio**k
    if w >= 1.0:
        return 1.0
    if w <= 0.0:
        return np.inf
    denom = np.log1p(-w)
    if denom == 0.0:
        return np.inf
    return max(1.0, np.ceil(np.log1p(-confidence) / denom))


@numba.njit(cache=True, nogil=True)
def trials_needed(k: int, count: int, n: int, confidence: float, cap: int) -> int:
    """F(k, r) for the inlier ratio ``count`` / ``n`` of the best model so far, capped at ``cap``
    (``cap`` before any inlier is known)."""
    w = min(1.0, count / n) if n > 0 else 0.0
    return int(min(trial_count(k, w, confidence), float(cap)))


def ransac_trials(k: int, r: float, confidence: float = 0.99, max_trials: int | None = None) -> int:
    """The paper's F(k, r): RANSAC trials needed to draw one all-inlier sample of size k.

    F(k, r) = ceil(log(1 - p) / log(1 - (1 - r)^k)), with r the outlier rate and p the confidence.

    Args:
        k: sample size (number of correspondences drawn per trial), >= 1.
        r: outlier rate in [0, 1].
        confidence: probability p in (0, 1) of drawing at least one all-inlier sample.
        max_trials: optional cap on the result.
    Returns:
        The number of trials (>= 1), or ``max_trials`` when r = 1 or the count exceeds it.
    """
    if k < 1:
        raise ValueError(f"sample size k must be >= 1, got {k}")
    if not 0.0 <= r <= 1.0:
        raise ValueError(f"outlier rate r must be in [0, 1], got {r}")
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must be in (0, 1), got {confidence}")
    n = trial_count(int(k), 1.0 - r, float(confidence))
    if max_trials is not None:
        n = min(n, max_trials)
    if n == math.inf:
        raise ValueError("F(k, r) is infinite for r = 1; pass max_trials")
    return max(1, int(n))


# --------------------------------------------------------------------------------------------
# The generic RANSAC loop (sample, minimal solve, score, local optimisation, adaptive stopping).
# Estimators plug in as `Problem`s; several problems ("arms") can race in one loop, which is how
# the separable estimator tries several line pairs and drops the ones whose support lags.
# --------------------------------------------------------------------------------------------


class Problem(Protocol):
    """One RANSAC arm: what to sample, how to solve a sample, how to score a model."""

    n: int  #: number of data points the inlier ratio refers to
    sample_size: int  #: points drawn per sample (the k of F(k, r))
    pool: np.ndarray  #: (P,) indices eligible for sampling

    def solve(self, samples: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(B, k) pool indices -> (models (K, ...), sample index of each model (K,))."""

    def score(self, models: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(K, ...) models -> (cost (K,), lower is better; inlier count (K,))."""

    def local_optimize(self, model: np.ndarray) -> np.ndarray:
        """Models (J, ...) refined from ``model`` and its inliers (J may be 0)."""


@dataclass
class RaceOptions:
    """How several arms share one RANSAC run.

    Attributes:
        add_after: total samples after which arm i+1 joins (arm 0 starts alone); arms beyond
            the list join when the previous entry times ``add_growth`` has been spent.
        drop_ratio: an arm whose best inlier count is below ``drop_ratio`` times the leader's...
        drop_alpha: ...after enough samples that a good arm would have found an all-inlier
            sample with probability ``1 - drop_alpha`` is dropped.
    """

    add_after: tuple[int, ...] = (40,)
    add_growth: float = 2.0
    drop_ratio: float = 0.8
    drop_alpha: float = 0.1


@dataclass
class RansacResult:
    model: Any
    cost: float
    count: int
    leader: int  #: index of the arm that produced the model (-1 when none)
    hypotheses: int  #: models scored (minimal-sample models and local-optimisation models)
    samples: list[int] = field(default_factory=list)  #: samples drawn per arm
    dropped: list[int] = field(default_factory=list)  #: arms dropped for lagging support
    converged: bool = False  #: adaptive stopping reached (False: stopped at max_samples)


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
) -> RansacResult:
    """Run RANSAC over one or more arms with adaptive stopping F(k, r) and local optimisation.

    Arm 0 starts; further arms are pulled from ``arms`` (lazily: an iterator may build each arm
    only when it joins) on the ``race`` schedule and are dropped when their support lags (see
    :class:`RaceOptions`). The loop stops when the arms that agree with the best model have
    drawn F(k, r) samples together for the inlier ratio of the best model, or when
    ``max_samples`` samples were drawn in all. An arm agrees when it holds the best model or its
    own best support is at least ``race.drop_ratio`` of it: arms whose fixed points are all
    inliers draw an all-inlier sample at the same rate w^k, so their samples pool (several good
    line pairs racing would otherwise each draw F(k, r) samples); a lagging arm's do not count.

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
    """
    race = race or RaceOptions()
    source = iter(arms)
    pool: list[Problem] = []
    samples: list[int] = []
    arm_best: list[int] = []  # best inlier count per arm
    arm_model: list[Any] = []  # best minimal-sample model per arm, and its cost
    arm_cost: list[float] = []
    arm_raw_count: list[int] = []  # inlier count of the arm's best minimal-sample model
    arm_checked: list[bool] = []  # arm's best model was locally optimised before a drop
    active: list[int] = []
    dropped: list[int] = []

    def join() -> bool:
        arm = next(source, None)
        if arm is None:
            return False
        pool.append(arm)
        samples.append(0)
        arm_best.append(-1)
        arm_model.append(None)
        arm_cost.append(np.inf)
        arm_raw_count.append(0)
        arm_checked.append(False)
        active.append(len(pool) - 1)
        return True

    join()
    best_model, best_cost, best_count, leader = None, np.inf, -1, -1
    extra_lo = 0
    hypotheses = 0

    def local_optimization(a: int, model: Any) -> None:
        """LO-RANSAC step from ``model`` of arm ``a``; updates the best model and arm_best."""
        nonlocal best_model, best_cost, best_count, leader, hypotheses
        lo = pool[a].local_optimize(model)
        if not len(lo):
            return
        lcost, lcount = pool[a].score(lo)
        hypotheses += len(lo)
        j = int(np.argmin(lcost))
        arm_best[a] = max(arm_best[a], int(lcount.max()))
        if lcost[j] < best_cost:
            best_model, best_cost, best_count, leader = lo[j], float(lcost[j]), int(lcount[j]), a

    def agrees(a: int) -> bool:
        """Arm ``a`` holds the best model or its best support is near the best model's."""
        return a == leader or arm_best[a] >= race.drop_ratio * best_count

    def pooled_samples() -> int:
        """Samples of the arms that agree with the best model (0 before there is one)."""
        if leader < 0:
            return 0
        return sum(n for a, n in enumerate(samples) if agrees(a))

    def drop_after(a: int) -> float:
        """Samples after which a lagging arm ``a`` is dropped: had its fixed points been
        right, it would have drawn an all-inlier sample by then with probability
        1 - drop_alpha (at the best model's inlier ratio)."""
        w = min(1.0, max(best_count, 0) / pool[a].n)
        p_good = w ** pool[a].sample_size
        return float(np.log(race.drop_alpha) / np.log(max(1e-300, 1.0 - p_good)))

    if initial is not None and pool:
        best_model, best_cost, best_count = initial
        leader = 0
    total = 0
    n_join = 0
    next_join = race.add_after[0] if race.add_after else max_samples
    converged = False

    while active:
        # one round: every active arm draws the same batch, sized by what is still needed and
        # by the most-sampled arm, so an arm that joins late races at the leader's pace (one
        # growing its own batches from 1 left a good line pair joining after a wrong one too
        # few samples to find its model)
        pace = max(1, max(samples[a] for a in active))
        for a in list(active):
            arm = pool[a]
            need = trials_needed(
                arm.sample_size, max(best_count, 0), arm.n, confidence, max_samples
            )
            need = max(need, min_samples)
            done = pooled_samples()
            if leader >= 0 and done >= need:
                break
            # batches grow 1, 1, 2, 4, ... so the sequential stopping rule is barely overshot
            b = max(1, min(need - done, batch, pace))
            b = min(b, max_samples - total)
            if b <= 0:
                continue
            smp = draw_samples(rng, arm.pool, arm.sample_size, b)
            samples[a] += b
            total += b
            models, _ = arm.solve(smp)
            if len(models) == 0:
                continue
            cost, count = arm.score(models)
            hypotheses += len(models)
            i = int(np.argmin(cost))
            arm_best[a] = max(arm_best[a], int(count.max()))
            improved = cost[i] < arm_cost[a]
            if improved:
                arm_model[a], arm_cost[a] = models[i], float(cost[i])
            if cost[i] < best_cost:
                best_model, best_cost, best_count, leader = (
                    models[i],
                    float(cost[i]),
                    int(count[i]),
                    a,
                )
            # LO-RANSAC: optimise every minimal-sample model that beats its arm's best
            # minimal-sample model so far. Comparing with the best *refined* model instead would
            # starve LO when minimal samples are badly conditioned (fixed line points), as their
            # raw support then stays below a refined wrong-basin model's; comparing across arms
            # would starve a good line pair racing a wrong one whose fixed points an H_e fits
            # exactly (repetitive texture): the wrong arm's raw models score higher.
            if improved:
                arm_raw_count[a] = int(count[i])
                local_optimization(a, models[i])
            elif extra_lo < max_extra_lo and count[i] >= extra_lo_ratio * arm_raw_count[a]:
                extra_lo += 1
                local_optimization(a, models[i])
        # adaptive stopping on the samples of the arms that agree with the best model
        if leader >= 0:
            arm = pool[leader]
            need = trials_needed(arm.sample_size, best_count, arm.n, confidence, max_samples)
            if pooled_samples() >= max(need, min_samples):
                converged = True
                break
        if total >= max_samples:
            break
        # racing: drop lagging arms (after one local optimisation of their best model, since a
        # minimal sample with fixed line points is often badly conditioned), let the next join
        if len(pool) > 1 and best_count > 0:
            for a in list(active):
                if agrees(a) or samples[a] < drop_after(a):
                    continue
                if not arm_checked[a] and arm_model[a] is not None:
                    arm_checked[a] = True
                    local_optimization(a, arm_model[a])
                    if agrees(a):
                        continue
                active.remove(a)
                dropped.append(a)
        if total >= next_join or not active:
            if join():
                n_join += 1
                next_join = (
                    race.add_after[n_join]
                    if n_join < len(race.add_after)
                    else int(np.ceil(next_join * race.add_growth))
                )
            else:
                next_join = max_samples + 1
    return RansacResult(
        model=best_model,
        cost=best_cost,
        count=max(best_count, 0),
        leader=leader,
        hypotheses=hypotheses,
        samples=samples,
        dropped=dropped,
        converged=converged,
    )
