"""The state one run of the robust loop shares between its core (``loop``) and its race policy
(``race``): the sample budget, the best model so far and the book-keeping of each arm."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from sepfm_ros.geometry.robust.contract import Problem
from sepfm_ros.geometry.robust.samplers import ProsacSampler

__all__ = ["Arm", "Best", "Budget"]


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
class Best:
    """The lowest-cost model of the run so far (``model`` None before any)."""

    model: Any = None
    cost: float = np.inf
    count: int = -1  #: its inlier count (-1 before any model)
    leader: int = -1  #: index of the arm that produced it (-1 before any model)


@dataclass
class Arm:
    """Book-keeping of one arm during a run."""

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
