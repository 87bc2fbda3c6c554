"""The fundamental-matrix RANSAC problem: seven- or eight-point samples, optionally with fixed
correspondences (the separable method's stage 2), symmetric-epipolar scoring, and LO refits.

Every method of :func:`sepfm_ros.geometry.estimate_fundamental` (ours and the baselines) samples,
solves, scores and refines through this one class, so their comparison is fair.
"""

from __future__ import annotations

from typing import get_args

import numba
import numpy as np

from sepfm_ros.geometry.epipolar import (
    apply_transform,
    denormalize_kernel,
    distances_kernel,
    homogeneous_columns,
    msac_kernel,
    sprt_msac_kernel,
)
from sepfm_ros.geometry.fundamental.correspondences import Correspondences
from sepfm_ros.geometry.fundamental.nonlinear import polish_local_optimization
from sepfm_ros.geometry.fundamental.options import LoScheme, Scoring, Solver
from sepfm_ros.geometry.fundamental.refine import iterative_refit, lmeds_refit
from sepfm_ros.geometry.robust.contract import Problem
from sepfm_ros.geometry.robust.lmeds import RobustScale, robust_scale
from sepfm_ros.geometry.solvers.eight_point import eight_point_kernel
from sepfm_ros.geometry.solvers.orientation import oriented_consistent
from sepfm_ros.geometry.solvers.seven_point import seven_point_kernel

SCORINGS = get_args(Scoring)


@numba.njit(cache=True, nogil=True)
def solve_samples_kernel(
    f1: np.ndarray,
    f2: np.ndarray,
    x1: np.ndarray,
    x2: np.ndarray,
    samples: np.ndarray,
    T1: np.ndarray,
    T2: np.ndarray,
    seven: bool,
    oriented: bool,
) -> tuple[np.ndarray, np.ndarray]:
    """Minimal (or fixed + sampled) solves of B samples, in one compiled call.

    f1, f2: (f, 2) fixed normalised correspondences put in front of every sample; x1, x2: (N, 2)
    normalised coordinates; samples: (B, k) indices; T1, T2: (3, 3) normalising transforms.
    seven: seven-point (each real root a model) or eight-point. oriented: a model whose sample
    (fixed points included) breaks the oriented epipolar constraint
    (``solvers.orientation.oriented_consistent``) is dropped. Returns (F (K, 3, 3) in px at unit
    Frobenius norm, (K,) sample index of each model).
    """
    n_keep, k, f = samples.shape[0], samples.shape[1], f1.shape[0]
    if n_keep == 0:
        return np.empty((0, 3, 3)), np.empty(0, dtype=np.int64)
    y1 = np.empty((n_keep, f + k, 2))
    y2 = np.empty((n_keep, f + k, 2))
    for b in range(n_keep):
        for j in range(f + k):
            for c in range(2):
                y1[b, j, c] = f1[j, c] if j < f else x1[samples[b, j - f], c]
                y2[b, j, c] = f2[j, c] if j < f else x2[samples[b, j - f], c]
    if seven:
        F_n, sid = seven_point_kernel(y1, y2)
    else:
        F_n = eight_point_kernel(y1, y2, np.ones((n_keep, f + k)))
        sid = np.arange(n_keep)
    F = np.empty_like(F_n)
    out_sid = np.empty_like(sid)
    n_out = 0
    for m in range(F_n.shape[0]):
        if oriented and not oriented_consistent(F_n[m], y1[sid[m]], y2[sid[m]]):
            continue
        if denormalize_kernel(F_n[m], T1, T2, F[n_out]):
            out_sid[n_out] = sid[m]
            n_out += 1
    return F[:n_out], out_sid[:n_out]


#: Local optimisation inside RANSAC: inlier-threshold factors (loosest first), Sampson IRLS
#: iterations per refit, and whether the refits are followed by the Levenberg-Marquardt step of
#: :func:`~sepfm_ros.geometry.fundamental.nonlinear.polish_local_optimization`. ``"sampson"``:
#: each refit is
#: Sampson-weighted, from 3x the threshold down (on forward motion, where points near the epipole
#: fit many wrong F, plain least squares stops in a wrong basin); ``"lm"``: the same refits, then
#: the truncated geometric error minimised from the best refit (and, on noisy matches, from the
#: sample's model) at a truncation that follows the matches' noise (a linear refit minimises an
#: algebraic error);
#: ``"plain"``: unweighted least squares at 2x and 1x the threshold.
LO_SCHEMES: dict[LoScheme, tuple[tuple[float, ...], int, bool]] = {
    "lm": ((3.0, 2.0, 1.5, 1.0), 2, True),
    "sampson": ((3.0, 2.0, 1.5, 1.0), 2, False),
    "plain": ((2.0, 1.0), 0, False),
}


class FundamentalProblem(Problem):
    """One RANSAC arm estimating F.

    Args:
        data: the correspondences.
        solver: "seven" (seven-point, k = 7 - f) or "eight" (eight-point, k = 8 - f).
        threshold: inlier threshold in px of symmetric epipolar distance.
        scoring: "msac" or "lmeds".
        fixed1, fixed2: (f, 2) pixel correspondences kept in every sample: none, the paper's 3
            line correspondences, or all line correspondences (f >= 3) as a least-squares block
            that fixes the same 3 degrees of freedom with the noise averaged.
        pool: indices of ``data`` eligible for sampling (default: all).
        lo: local optimisation scheme, a key of :data:`LO_SCHEMES`.
        scale: lmeds only: the :class:`RobustScale` shared by the arms of one estimate (a new one
            by default).

    Scoring "lmeds": cost = median of d^2 over all matches; the inlier count of a model is the
    number of matches within the robust inlier threshold 2.5 sigma of the best model so far
    (sigma of :func:`robust_scale`), so the count of the best model is its robust inlier set
    and counts of other models and arms compare with it; ``threshold`` plays no part.
        lo_data: the matches local optimisation fits on (refits and Levenberg-Marquardt, MSAC
            scoring), e.g. ``data.spread(k)``; its models are scored on ``data`` (default:
            ``data`` itself).
        fixed_tol: px (0: no check), the fixed correspondences' check: every one of them must
            lie within ``fixed_tol`` of a model for the arm's samples to be able to reach it
            (:meth:`fixed_inliers`).
        oriented: drop the models for which the sample's own matches break the oriented
            epipolar constraint (``solvers.orientation``), before they are scored.
        race_share: in a race (``robust.race``), the most share of all samples this arm
            draws while an arm without a share is active (1: no limit).
    """

    def __init__(
        self,
        data: Correspondences,
        solver: Solver = "seven",
        threshold: float = 1.0,
        scoring: Scoring = "msac",
        fixed1: np.ndarray | None = None,
        fixed2: np.ndarray | None = None,
        pool: np.ndarray | None = None,
        lo: LoScheme = "lm",
        scale: RobustScale | None = None,
        lo_data: Correspondences | None = None,
        fixed_tol: float = 0.0,
        oriented: bool = False,
        race_share: float = 1.0,
    ) -> None:
        if lo not in LO_SCHEMES:
            raise ValueError(
                f"unknown local optimisation {lo!r}; expected one of {list(LO_SCHEMES)}"
            )
        self.lo_factors, self.lo_irls, self.lo_lm = LO_SCHEMES[lo]
        if solver not in ("seven", "eight"):
            raise ValueError(f"unknown solver {solver!r}")
        if scoring not in SCORINGS:
            raise ValueError(f"unknown scoring {scoring!r}; expected one of {SCORINGS}")
        self.data = data
        self.lo_data = data if lo_data is None else lo_data
        self.solver = solver
        self.threshold = float(threshold)
        self.scoring = scoring
        f = 0 if fixed1 is None else min(3, len(fixed1))  # DOF fixed by line points
        self.f1 = np.zeros((0, 2)) if fixed1 is None else apply_transform(data.T1, fixed1)
        self.f2 = np.zeros((0, 2)) if fixed2 is None else apply_transform(data.T2, fixed2)
        self.f1, self.f2 = np.ascontiguousarray(self.f1), np.ascontiguousarray(self.f2)
        #: the fixed correspondences as homogeneous pixel columns ((3, f), (3, f)) for
        #: :meth:`fixed_inliers` (None without the check): made once, checked per best model
        self.fixed_px = (
            (
                homogeneous_columns(np.asarray(fixed1, dtype=np.float64)),
                homogeneous_columns(np.asarray(fixed2, dtype=np.float64)),
            )
            if f > 0 and fixed_tol > 0
            else None
        )
        self.fixed_tol = float(fixed_tol)
        self.oriented = bool(oriented)
        self.race_share = float(race_share)
        self.sample_size = (7 if solver == "seven" else 8) - f
        self.pool = np.arange(len(data)) if pool is None else np.asarray(pool, dtype=np.int64)
        self.n = len(data)
        #: p of the robust scale: the points that determine a model (fixed ones included)
        self.model_points = 7 if solver == "seven" else 8
        self.scale = scale if scale is not None else RobustScale()
        # lmeds: counts are within the best model's robust scale; the race re-counts the arms
        # (recount: the size of ``inliers``) when the scale shrinks
        self.relative_counts = scoring == "lmeds"

    @property
    def plain_solve(self) -> bool:
        """Whether :meth:`solve` is :func:`solve_samples_kernel` on the fixed points alone (what
        the compiled loop of :mod:`~sepfm_ros.geometry.fundamental.compiled_loop` runs)."""
        return True

    def free_sample_size(self) -> int:
        """Points of a seven- or eight-point sample, fixed ones included."""
        return self.model_points

    def fixed_inliers(self, model: np.ndarray) -> bool:
        """Whether every fixed correspondence lies within ``fixed_tol`` px (symmetric epipolar
        distance) of ``model`` (3, 3), pixels; True without the check. Every model this arm
        solves passes through its fixed points, so when the best model leaves one of them
        out, no sample of this arm can be all-inlier for it (a wrong line match among the
        fixed points, or a wrong line pair)."""
        if self.fixed_px is None:
            return True
        F = np.ascontiguousarray(model, dtype=np.float64).reshape(1, 3, 3)
        d = distances_kernel(F, *self.fixed_px)[0]  # symmetric_epipolar_distance's kernel
        return bool(np.all(d < self.fixed_tol))

    def solve(self, samples: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(B, k) indices -> (F (K, 3, 3) in pixels, sample index (K,))."""
        return solve_samples_kernel(
            self.f1, self.f2, self.data.x1, self.data.x2, samples, self.data.T1, self.data.T2,
            self.solver == "seven", self.oriented,
        )  # fmt: skip

    def distances(self, F: np.ndarray) -> np.ndarray:
        """(K, 3, 3) -> (K, N) symmetric epipolar distances in px."""
        return self.data.distances(F)

    def score(self, models: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if self.scoring == "msac":  # compiled, no (K, N) distance matrix
            return msac_kernel(models, self.data.X1, self.data.X2, self.threshold)
        d = self.distances(models)
        cost = np.median(d * d, axis=1)
        self.scale.update(float(robust_scale(cost.min(), self.n, self.model_points)))
        return cost, np.count_nonzero(d < self.scale.threshold, axis=1)

    def inliers(self, model: np.ndarray) -> np.ndarray:
        """(N,) bool: matches within the inlier threshold of ``model`` (3, 3) (lmeds: within
        the current robust threshold)."""
        thr = self.scale.threshold if self.scoring == "lmeds" else self.threshold
        return self.data.distances(model) < thr

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
        """:meth:`score` with early rejection (SPRT / bail-out, see
        :func:`~sepfm_ros.geometry.epipolar.sprt_msac_kernel`): (cost, inf when rejected;
        inlier count; points read; rejected by the SPRT). LMedS scores every point."""
        if self.scoring != "msac":
            cost, count = self.score(models)
            M = len(models)
            return cost, count, np.full(M, self.n, dtype=np.int64), np.zeros(M, dtype=bool)
        return sprt_msac_kernel(
            models, self.data.X1, self.data.X2, self.threshold, order, self.data.in_order(order),
            log_A, log_in, log_out, bail_cost, bail_count,
        )  # fmt: skip

    def local_optimize(self, model: np.ndarray) -> np.ndarray:
        """Iterative least-squares refits of ``model`` on its inliers (see iterative_refit);
        lmeds: refits on its robust inliers (see lmeds_refit), judged by the caller by their
        median."""
        if self.scoring == "lmeds":
            return lmeds_refit(model, self.data, self.model_points, irls_iterations=0)
        return iterative_refit(
            model, self.lo_data, self.threshold, factors=self.lo_factors,
            irls_iterations=self.lo_irls,
        )  # fmt: skip

    def polish(self, model: np.ndarray, start: np.ndarray) -> np.ndarray:
        """The ``"lm"`` scheme's Levenberg-Marquardt step (polish_local_optimization) from
        ``start`` (3, 3), the best of the sample's ``model`` and its refits: (K, 3, 3) models,
        K = 0 for the other schemes and for lmeds."""
        if not self.lo_lm or self.scoring == "lmeds":
            return np.empty((0, 3, 3))
        return polish_local_optimization(model, start, self.lo_data, self.threshold)
