"""Options of the robust loop: sampling variants (PROSAC, SPRT, bail-out) and the race of arms."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

__all__ = ["PoolRule", "RaceOptions", "SamplingOptions"]

#: which arms' samples pool toward the stop (:class:`RaceOptions`)
PoolRule = Literal["support", "model"]


@dataclass
class RaceOptions:
    """How several arms share one RANSAC run.

    Attributes:
        add_after: total samples after which arm i+1 joins (arm 0 starts alone); arms beyond
            the list join when the previous entry times ``add_growth`` has been spent.
        drop_ratio: an arm whose best inlier count is below ``drop_ratio`` times the leader's...
        drop_alpha: ...after enough samples that a good arm would have found an all-inlier
            sample with probability ``1 - drop_alpha`` is dropped.
        pool_rule: which arms' samples count toward the pooled F(k, r) stop besides the
            leader's (the arm holding the best model): ``"support"``, arms whose best inlier
            count is at least ``pool_ratio`` times the best model's; ``"model"``, arms whose
            lowest-cost model has at least ``pool_ratio`` of the best model's inliers among its
            own inliers (needs the problems' ``inliers``; else ``"support"``).
        pool_ratio: the share of that rule.
    """

    add_after: tuple[int, ...] = (40,)
    add_growth: float = 2.0
    drop_ratio: float = 0.8
    drop_alpha: float = 0.1
    pool_rule: PoolRule = "support"
    pool_ratio: float = 0.8


@dataclass
class SamplingOptions:
    """Sampling and verification variants of :func:`run_ransac` (all off: plain RANSAC).

    Attributes:
        prosac: PROSAC sampling of each arm's pool in its order (best first); the adaptive
            stopping is still F(k, r) over all samples drawn (see docs in run_ransac).
        prosac_growth: T_N of the PROSAC schedule; 0 means ``max_samples``.
        sprt: Wald's SPRT on minimal-sample models (Matas & Chum 2008), with epsilon the best
            model's inlier ratio and delta the inlier ratio seen in rejected models.
        bailout: reject a minimal-sample model as soon as it can neither beat its arm's best
            cost nor reach the support that would earn it a local optimisation (exact).
        sprt_model_time: t_M, the time to draw and solve one sample in units of one point's
            verification, in the SPRT's threshold A.
        sprt_delta: initial delta (probability that a point is consistent with a bad model).
    """

    prosac: bool = False
    prosac_growth: int = 0
    sprt: bool = False
    bailout: bool = False
    sprt_model_time: float = 200.0
    sprt_delta: float = 0.01
