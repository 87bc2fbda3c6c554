"""The contract between the robust loop and a problem it solves: one base class with every hook
the loop calls and its default.

A problem (one "arm" of the loop) holds N data points, of which it samples ``sample_size`` at a
time from its ``pool``. The loop calls, per batch of samples:

1. :meth:`Problem.solve` on the samples -> models;
2. :meth:`Problem.score` (or :meth:`Problem.score_early` with SPRT / bail-out) -> cost and
   inlier count per model; the lowest cost wins everywhere;
3. on a model that beats its arm's best minimal-sample model: :meth:`Problem.local_optimize`
   -> refined models, scored; then :meth:`Problem.polish` from the best of them, whose models
   (if any) are offered in their place;
4. the stopping rule: F(k, r) samples at the best model's inlier ratio, pooled over the arms
   that agree with it (``robust.race``), where :meth:`Problem.fixed_inliers` says whether an
   arm's samples can reach the best model at all, and :meth:`Problem.inliers` /
   :meth:`Problem.recount` compare arms.
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np

__all__ = ["Problem"]


class Problem(ABC):
    """One arm of the robust loop: what to sample, how to solve a sample, how to score a model.

    Attributes:
        n: data points the inlier ratio refers to (N).
        sample_size: points drawn per sample (the k of F(k, r)).
        pool: (P,) indices of the points eligible for sampling, best first (PROSAC's order).
        race_share: in a race, the most share of all samples this arm draws while an arm
            without a share is active (< 1: a hedge that runs beside the others at a fraction
            of their pace); 1: no limit.
        relative_counts: the inlier counts of :meth:`score` depend on the best model so far
            (LMedS: matches within its robust scale). Then an arm's support is the count of its
            lowest-cost model, re-counted (:meth:`recount`) whenever the best model improves,
            instead of the largest count any of its models had.
    """

    n: int
    sample_size: int
    pool: np.ndarray
    race_share: float = 1.0
    relative_counts: bool = False

    @abstractmethod
    def solve(self, samples: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(B, k) pool entries -> (models (K, ...), index into ``samples`` of each (K,))."""

    @abstractmethod
    def score(self, models: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(K, ...) models -> (cost (K,), lower is better; inlier count (K,))."""

    @abstractmethod
    def inliers(self, model: np.ndarray) -> np.ndarray:
        """(N,) bool: the points within the inlier threshold of one model."""

    def score_early(
        self,
        models: np.ndarray,
        order: np.ndarray,
        log_A: float,
        log_in: float,
        log_out: float,
        bail_cost: float,
        bail_count: int,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`score` with early rejection, reading the points in ``order`` (N,): Wald's SPRT
        with threshold log A and the per-point log likelihood ratios ``log_in`` / ``log_out``
        (log A = inf: no SPRT), and the bail-out (reject once the model can neither get below
        ``bail_cost`` nor reach ``bail_count`` inliers). Returns (cost, inf when rejected; inlier
        count, of the points read when rejected; points read (K,); rejected by the SPRT (K,)).

        Default: no early rejection, every point read."""
        cost, count = self.score(models)
        k = len(models)
        return cost, count, np.full(k, self.n, dtype=np.int64), np.zeros(k, dtype=bool)

    def local_optimize(self, model: np.ndarray) -> np.ndarray:
        """Models (J, ...) refined from ``model`` and its inliers (J may be 0). Default: none."""
        return np.empty((0, *np.shape(model)))

    def polish(self, model: np.ndarray, start: np.ndarray) -> np.ndarray:
        """Models (J, ...) of a second local-optimisation step from ``start``, the best of the
        sample's ``model`` and its :meth:`local_optimize` results; when J > 0 they are offered
        instead of those results. Default: none (J = 0)."""
        return np.empty((0, *np.shape(model)))

    def fixed_inliers(self, model: np.ndarray) -> bool:
        """For problems whose samples all contain fixed points (the separable stage 2): whether
        those points are inliers of ``model``. When they are not inliers of the best model, no
        sample of this arm can be all-inlier for it: the arm stops counting toward the stop and
        is dropped. Default: True (no fixed points)."""
        return True

    def recount(self, model: np.ndarray) -> int:
        """With ``relative_counts``: the inlier count of ``model`` under the current best model
        (called when the best model improves). Default: the size of :meth:`inliers`."""
        return int(np.count_nonzero(self.inliers(model)))

    def free_sample_size(self) -> int:
        """Points a sample without this arm's fixed points needs (e.g. 7 for a seven-point
        model, whatever is fixed); the loop drops an arm whose fixed points are outliers of
        the best model at once when F(this, r) samples fit in the budget left. Default:
        ``sample_size``."""
        return self.sample_size
