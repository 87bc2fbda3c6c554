"""One estimate's fundamental-matrix task: the matches, the method's solver and scoring, the
options of the F side, the random generator and the sample budget every stage shares; and the
standard RANSAC over all matches that the baselines run and the separable method falls back to."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import Any

import numpy as np

from sepfm_ros.geometry.fundamental.compiled_loop import CompiledLoop
from sepfm_ros.geometry.fundamental.correspondences import Correspondences
from sepfm_ros.geometry.fundamental.options import (
    Checks,
    LocalOptimization,
    Sampling,
    Scoring,
    Solver,
)
from sepfm_ros.geometry.fundamental.problem import FundamentalProblem
from sepfm_ros.geometry.robust.lmeds import RobustScale
from sepfm_ros.geometry.robust.loop import Budget, Loop, RansacResult, make_loop
from sepfm_ros.geometry.robust.trials import ransac_trials

__all__ = ["FundamentalTask", "sample_cap"]

#: The automatic sample cap (``max_samples`` 0, :func:`sample_cap`): matches scored in all,
#: and the fewest and most samples.
SCORING_BUDGET = 10_000_000
MIN_AUTO_SAMPLES = 10_000
MAX_AUTO_SAMPLES = 100_000


def sample_cap(max_samples: int, n: int) -> int:
    """The samples one estimate of ``n`` matches may draw: ``max_samples`` when positive, else
    ``SCORING_BUDGET`` / n within [``MIN_AUTO_SAMPLES``, ``MAX_AUTO_SAMPLES``].

    The automatic cap bounds the scoring work (samples x matches) rather than the samples:
    10,000 samples from 1,000 matches up, up to 100,000 (PoseLib's cap) for fewer. A pair with
    few matches and few true ones among them needs the most samples (13 true of 55: F(7, 0.24)
    is about 100,000 seven-point samples) and each costs the least to score.
    """
    if max_samples > 0:
        return int(max_samples)
    return int(min(MAX_AUTO_SAMPLES, max(MIN_AUTO_SAMPLES, SCORING_BUDGET // max(n, 1))))


@dataclass
class FundamentalTask:
    """What every step of one estimate shares: the matches, the method's solver and scoring,
    the thresholds, the fundamental side's options and the random generator."""

    data: Correspondences
    solver: Solver
    scoring: Scoring
    threshold: float
    confidence: float
    sampling: Sampling
    local: LocalOptimization
    checks: Checks
    rng: np.random.Generator
    budget: Budget  #: :func:`sample_cap` samples, shared by every stage of this estimate
    scale: RobustScale = field(default_factory=RobustScale)  #: LMedS: shared by all arms
    #: (N,) bool, matches on a periodic line pair (``periodic_check``): left out of the pools
    #: of the stage-2 arms built after the pair was found periodic, last in the fallback's
    #: pool (PROSAC draws them last); they are still scored
    ambiguous: np.ndarray | None = None

    def pool_order(self, mask: np.ndarray) -> np.ndarray:
        """Indices where (N,) bool ``mask``, best first, the ambiguous matches last."""
        if self.ambiguous is None:
            return np.flatnonzero(mask)
        return np.concatenate(
            [np.flatnonzero(mask & ~self.ambiguous), np.flatnonzero(mask & self.ambiguous)]
        )

    @property
    def lmeds(self) -> bool:
        return self.scoring == "lmeds"

    @cached_property
    def lo_data(self) -> Correspondences:
        """The matches local optimisation fits on (option ``lo_matches``), shared by every arm."""
        k = self.local.lo_matches
        return self.data if k == 0 else self.data.spread(k)

    @property
    def model_points(self) -> int:
        return 7 if self.solver == "seven" else 8

    def min_samples(self, k: int) -> int:
        """Samples drawn at least: LMedS F(k, 0.5) (see :mod:`sepfm_ros.geometry.estimator`),
        else 1."""
        if not self.lmeds:
            return 1
        return min(ransac_trials(k, 0.5, self.confidence), self.budget.limit)

    def whole(self, race_share: float = 1.0) -> FundamentalProblem:
        """The problem over all matches (no fixed points), the ambiguous ones last in its pool;
        ``race_share``: its most share of a race's samples (``FundamentalProblem``)."""
        pool = None if self.ambiguous is None else self.pool_order(np.ones(len(self.data), bool))
        return FundamentalProblem(
            self.data, self.solver, self.threshold, self.scoring, pool=pool, scale=self.scale,
            lo=self.local.lo, lo_data=self.lo_data, oriented=self.checks.oriented,
            race_share=race_share,
        )  # fmt: skip

    def standard(self, initial: tuple[Any, float, int] | None = None) -> RansacResult:
        """Standard RANSAC over all matches (optionally starting from ``initial``), on what is
        left of the budget.

        PROSAC's schedule reaches the whole pool (uniform sampling) when what is left of the
        budget is spent (T_N = samples left): a fallback after stage 2 has less than
        ``max_samples`` left and would otherwise stop while still drawing from the top of the
        pool only, which on repetitive texture (a periodic row or a chessboard ranked first)
        holds the ambiguous matches and the plane.
        """
        return self.standard_loop(self.rng, initial).run()

    def standard_loop(
        self, rng: np.random.Generator, initial: tuple[Any, float, int] | None = None
    ) -> Loop:
        """The loop :meth:`standard` runs, drawing from ``rng``, before its first sample (the
        separable method probes the inlier ratio with its first rounds, ``Loop.start``)."""
        arm = self.whole()
        sampling = replace(self.sampling.loop(), prosac_growth=max(1, self.budget.left()))
        return make_loop(
            [arm], rng, self.confidence, self.budget.limit,
            min_samples=self.min_samples(arm.sample_size), initial=initial,
            budget=self.budget, sampling=sampling, cls=CompiledLoop,
        )  # fmt: skip
