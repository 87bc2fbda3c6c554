"""The contract between the robust loop and a problem it solves."""

from __future__ import annotations

from typing import Protocol

import numpy as np

__all__ = ["Problem"]


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

    # Optional: ``polish(model, start) -> models (J, ...)``, a second local-optimisation step from
    # ``start``, the best of ``model`` and its ``local_optimize`` results; when it returns
    # models they are offered instead of those results.
    # Optional: ``fixed_inliers(model) -> bool``, for problems whose samples all contain fixed
    # points (the separable stage 2): whether those points are inliers of ``model``. When they
    # are not inliers of the best model, no sample of the arm can be all-inlier for it: the
    # arm stops counting toward the stop and is dropped (see ``_Run.consistent``).
    # Optional: ``recount(model) -> int``, for problems whose inlier counts depend on the best
    # model so far (LMedS: matches within its robust scale). With it an arm's support is the
    # count of its lowest-cost model, re-counted whenever the best model improves, instead of
    # the largest count any of its models had.
    # Optional: ``race_share`` (float < 1), the most of all samples the arm may draw while an
    # arm without a share is active (a hedge that runs beside the others at a fraction of
    # their pace, e.g. stage 2's arm without fixed points).
