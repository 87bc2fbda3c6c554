"""Public entry point: :func:`estimate_fundamental` for the separable method and its baselines.

Methods (all through the same sampler, scoring, local optimisation and final refinement):

============  ================================================================================
``sep4``      line pair -> H_e (3 points, stage 1) -> 3 fixed + 4 sampled, seven-point (stage 2)
``sep5``      as sep4 with 3 fixed + 5 sampled, eight-point
``sep4-lmeds`` / ``sep5-lmeds``  the same as least median of squares (LMedS)
``ransac7``   standard RANSAC, seven-point, MSAC scoring
``ransac8``   standard RANSAC, eight-point, MSAC scoring
``lmeds7``    least median of squares, seven-point
``lmeds8``    least median of squares, eight-point (the paper's LMedS baseline)
============  ================================================================================

The ``-lmeds`` methods and ``lmeds7`` / ``lmeds8`` are least median of squares (Rousseeuw & Leroy
1987; Zhang 1998 for F), with no inlier threshold:

- every hypothesis (minimal-sample model, local refit, final refit) is scored by the median of
  its squared symmetric epipolar distances over all matches; the lowest median wins everywhere,
  MSAC costs are never used;
- robust scale sigma = 1.4826 (1 + 5 / (n - p)) sqrt(median d^2) (p = 7 or 8 points per model),
  robust inliers d < 2.5 sigma; local optimisation refits the robust inliers
  (:func:`~sepfm_ros.geometry.refine.lmeds_refit`);
- number of samples: F(k, r) with r = 1 - (robust inliers of the best model so far) / N, but at
  least F(k, 0.5) (capped at ``max_samples``). The floor is needed: a wrong model has broad
  residuals, so its robust scale is large and nearly every match falls within 2.5 sigma; the
  adaptive rule alone would stop after the first few samples on a wrong model. F(k, 0.5) is the
  classic LMedS choice (an outlier-free sample with confidence p whenever fewer than half of
  the matches are outliers, LMedS's breakdown point). The racing arms of the separable variants
  compare robust inlier counts under the best model's robust scale;
- final model: the best model and its normalised eight-point refits on its robust inliers
  (Sampson IRLS with ``refine``), the lowest median kept; then the robust scale and the inlier
  mask are computed once from it: Rousseeuw & Leroy's reweighted scale sigma* = sqrt(sum w d^2
  / (sum w - p)) over the matches within 2.5 sigma (the median-based sigma is inflated by the
  outliers when there are any), ``Estimate.scale`` = sigma*, inliers d < 2.5 sigma*.

``threshold`` is not used to score or select an LMedS model nor to mark its inliers; it only
serves the degeneracy checks (no motion, the plane-and-parallax check, inliers along one line)
and the breakdown check: with more than half of the matches outliers the median residual is an
outlier's and the robust scale grows to tens of px; when the final robust scale exceeds
``threshold`` the status says so (``"unreliable: ..."``) instead of "ok".
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, fields, replace
from functools import cached_property
from typing import Any

import numba
import numpy as np

from sepfm_ros.geometry.correspondences import Correspondences
from sepfm_ros.geometry.degeneracy import (
    PLANE_TOLERANCE,
    PlaneCheck,
    plane_and_parallax,
    transfer_error,
)
from sepfm_ros.geometry.epipolar import msac_kernel, normalize_fundamental
from sepfm_ros.geometry.estimate import Estimate, StatusCode
from sepfm_ros.geometry.fundamental_problem import (
    LO_SCHEMES,
    FundamentalProblem,
    RobustScale,
    lmeds_final_inliers,
)
from sepfm_ros.geometry.inner_sampling import inner_sampling
from sepfm_ros.geometry.line_homography_fit import LineHomographyFit, fit_line_homography
from sepfm_ros.geometry.line_pairs import (
    LinePair,
    LineSearchOptions,
    find_line_pairs,
    line_parameter,
    working_scale,
)
from sepfm_ros.geometry.nonlinear import polish_final
from sepfm_ros.geometry.periodic import is_periodic, shifted_plane_copy
from sepfm_ros.geometry.ransac import (
    Budget,
    RaceOptions,
    RansacResult,
    SamplingOptions,
    ransac_trials,
    run_ransac,
)
from sepfm_ros.geometry.refine import iterative_refit, lmeds_refit
from sepfm_ros.geometry.significance import MAX_LOG10_NFA, consensus_log10_nfa

# method -> (separable?, solver, scoring)
_METHODS: dict[str, tuple[bool, str, str]] = {
    "sep4": (True, "seven", "msac"),
    "sep5": (True, "eight", "msac"),
    "sep4-lmeds": (True, "seven", "lmeds"),
    "sep5-lmeds": (True, "eight", "lmeds"),
    "ransac7": (False, "seven", "msac"),
    "ransac8": (False, "eight", "msac"),
    "lmeds7": (False, "seven", "lmeds"),
    "lmeds8": (False, "eight", "lmeds"),
}
METHODS = tuple(_METHODS)
#: The method of the node, ``process``, ``eval``'s comparisons and the library when none is named:
#: the one that measures best (docs/benchmarks.md, ablation and hard-set sections).
DEFAULT_METHOD = "sep4"
TRIPLES = ("raw", "synthesized", "all")
RACE_POOLS = ("support", "model")
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


#: Most 3-point samples of stage 1 per line pair and control-point orientation (two orientations).
STAGE1_MAX_SAMPLES = 200
#: Tolerance (working px) of the periodic line-pair test (``periodic_check``): a point is on a
#: progression's node within min(this, 0.15 of the local period).
PERIODIC_TOLERANCE = 1.0


@dataclass(frozen=True)
class EstimatorOptions:
    """Options of :func:`estimate_fundamental` beyond method, threshold, confidence and seed.

    Values are converted to the field's type (``int``, ``float``, ``bool``) and checked when the
    object is made; bad values raise ``ValueError``.

    Attributes:
        max_samples: cap on the samples of one estimate, shared by all its stages (the
            separable method's 3-point samples of stage 1, stage 2's racing arms and the
            fallback), so a separable method draws no more than a baseline may; 0 (default):
            :func:`sample_cap` of the number of matches.
        refine: Sampson (IRLS) refinement of the final model.
        hough_width: working resolution of the line search, px.
        hough_min_votes: least votes of a Hough line.
        line_distance: C, the point-line incidence distance, working px (in image px
            C x image width / ``hough_width``: 7.3 px at KITTI's 1241 px, 3.75 px at 640 px).
        hough_points: best matches drawn into the binary images of the line search.
        max_line_pairs: line pairs whose stage-2 arms race.
        line_threshold: T1, the H_e inlier threshold of stage 1, working px. T1 and C scale
            with the image width, not with F's threshold; their values against image-px and
            other working-px values: docs/benchmarks.md, section "Race pooling and line
            thresholds" (bench_race_lines.py). Looser values (1.5 / 4.5) let a wrong F pass
            as "ok" on a synthetic plane-majority scene (test_plane_sampling.py).
        min_line_inliers: line correspondences that must agree with H_e (>= 3).
        triple: ``"raw"`` sample points, ``"synthesized"`` from the refined H_e, or ``"all"``
            H_e inliers as the fixed line correspondences of stage 2.
        plane_check: DEGENSAC-style plane-and-parallax check of the final F (degeneracy.py).
        lo: local optimisation inside RANSAC, ``"lm"`` (Sampson-weighted refits from 3x the
            threshold down, then Levenberg-Marquardt on the truncated geometric error),
            ``"sampson"`` (the refits alone) or ``"plain"`` (least squares at 2x and 1x); see
            ``fundamental_problem.LO_SCHEMES``.
        prosac: PROSAC sampling (best matches first) in every RANSAC loop (ransac.py).
        sprt: SPRT early rejection of minimal-sample models (Matas & Chum) in every loop.
        bailout: exact early rejection of minimal-sample models that cannot matter.
        plane_check_adaptive: the plane check tries off-plane pairs until F(2, w) were tried
            (w: the best candidate's off-plane inlier share) instead of all 300.
        sample_plane_check: separable stage 2 rejects, before solving, a sample two of whose
            points lie on one plane with the fixed line points (3 line + 2 points on one
            homography: the sample is plane-degenerate); it still counts as drawn. Off by
            default: on 20 plane-majority scenes it cut sep4's hypotheses (323 -> 238 median,
            with the final check) but did not replace the final check, and on real pairs
            (KITTI, forward motion: most pairs look near-coplanar with a line at 1-2 px) it
            lowered sep4/sep5's F-score.
        sample_plane_factor: that check's tolerance on the homography's transfer error, times
            the threshold.
        periodic_check: a line pair whose H_e inliers on line 1 lie on one projective
            arithmetic progression (equally spaced 3D points: a row of windows, a chessboard
            row; ``periodic.is_periodic`` at 2 T1) is ambiguous, its H_e may be off by a
            period: its stage-2 arm joins the race only after those of the other line pairs, and
            its matches (ambiguous: they may be off by a period) are not sampled by the arms
            built after it was found and come last in the fallback's PROSAC order. Off by
            default: on the real sets it fired on 1-3 % of the pairs, all matched correctly,
            and lowered sep4's F-score there slightly (docs/design.md, repetitive structure).
        shifted_plane_check: the final plane check discounts matches on a period-shifted copy
            of the plane (``periodic.shifted_plane_copy``; a chessboard matched one square off)
            and then challenges F with plane-and-parallax candidates.
        final_polish: with ``lo="lm"``, the final model is refined once more by
            Levenberg-Marquardt (``nonlinear.polish_final``): on noisy matches (noise
            truncation at least 1.5x the threshold: ORB, video frames) at a truncation of 2.5x
            the threshold; at thresholds of 3 px and more also at a third of it, kept when its
            multi-scale cost is lower (a wide threshold lets wrong matches within it pull the
            fit on pairs with few true matches). Precise matches at 1 px keep the model.
        lo_matches: local optimisation (refits and Levenberg-Marquardt; MSAC-scored methods,
            the ``-lmeds`` ones refit on all) fits on at most this many matches, taken evenly
            along the match order (``Correspondences.spread``; 0: on all); its models are
            scored on all matches, and the final model is refitted on all of them. Its cost then
            stops growing with the matches (docs/design.md, local optimisation).
        fixed_point_check: a stage-2 arm whose fixed line correspondences (the triple) are not
            all within ``fixed_point_check`` times the threshold of the best model so far is
            dropped, and its samples no longer count toward the F(k, r) stop: every model it
            solves passes through them, so none of its samples can be all-inlier for that
            model. The next line pair's arm or the fallback goes on. Without it, a triple
            holding a match that lies near the line but is wrong (the extreme H_e inliers are
            where such matches gather) let stage 2 stop on a worse basin (docs/design.md,
            fixed-point check). 0: off; not applied with ``triple="all"`` (a least-squares
            block, not passed through exactly) or with the LMedS methods.
        inner_samples: inner sampling of the final model (``inner_sampling.py``; LO-RANSAC's
            inner RANSAC, once per estimate): this many samples of 14 of its inliers are fitted
            by least squares, the best starts the local optimisation's refits (no LM step), and
            a refit is kept if it lowers the MSAC cost at the threshold and not at the noise
            truncation. A
            search that stops after few samples (the separable method's saving) tries few
            basins; this tries one more from the final inliers. 0: off; not with LMedS.
        oriented: every RANSAC stage drops, before scoring, the models for which the
            sample's own matches (fixed line points included) break the oriented epipolar
            constraint (``solvers/orientation.py``): no scene point behind a camera. Most are
            spurious roots of the seven-point cubic. Off by default: at high outlier rates a
            contaminated sample's model that breaks it can still be near the true F, and its
            local optimisation then finds the best model (docs/design.md).
        race_pool, race_pool_ratio: which racing stage-2 arms' samples count toward the pooled
            F(k, r) stop besides the leader's: ``"support"``, arms with at least
            ``race_pool_ratio`` of the best model's inlier count; ``"model"``, arms whose best
            model has at least ``race_pool_ratio`` of the best model's inliers among its own
            (``RaceOptions.pool_rule`` / ``pool_ratio``; docs/benchmarks.md, race and line
            thresholds section).
        unfixed_share: when fewer than ``max_line_pairs`` line pairs give a stage-2 arm, an arm
            without fixed points (standard RANSAC's samples, k = 7 or 8) joins the race after
            them and draws at most this share of stage 2's samples while another arm is
            active. Its samples count toward the pooled stop at F(k, r) / F(7 or 8, r) of a
            fixed arm's. It hedges a fixed triple that holds a wrong match near its line: with
            only one short line pair, stage 2 can converge on a model that passes through that
            match (docs/design.md, unfixed arm). 0: off.
    """

    max_samples: int = 0
    refine: bool = True
    hough_width: int = 512
    hough_min_votes: int = 4
    line_distance: float = 3.0
    hough_points: int = 300
    max_line_pairs: int = 4
    line_threshold: float = 1.0
    min_line_inliers: int = 4
    triple: str = "raw"
    plane_check: bool = True
    lo: str = "lm"
    prosac: bool = True
    sprt: bool = True
    bailout: bool = True
    plane_check_adaptive: bool = True
    sample_plane_check: bool = False
    sample_plane_factor: float = 2.0
    periodic_check: bool = False
    shifted_plane_check: bool = True
    final_polish: bool = True
    lo_matches: int = 600
    fixed_point_check: float = 1.5
    inner_samples: int = 20
    oriented: bool = False
    race_pool: str = "support"
    race_pool_ratio: float = 0.8
    unfixed_share: float = 0.25

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            kind = {"int": int, "float": float, "bool": bool, "str": str}[str(f.type)]
            try:
                converted = kind(value)
            except (TypeError, ValueError) as exc:
                raise ValueError(f"option {f.name} must be {f.type}, got {value!r}") from exc
            if kind is float and not np.isfinite(converted):
                raise ValueError(f"option {f.name} must be finite, got {value!r}")
            object.__setattr__(self, f.name, converted)
        least = {"max_samples": 0, "inner_samples": 0, "hough_width": 1, "hough_min_votes": 1,
                 "hough_points": 1, "max_line_pairs": 1, "min_line_inliers": 3}  # fmt: skip
        for name, low in least.items():
            if getattr(self, name) < low:
                raise ValueError(f"option {name} must be >= {low}, got {getattr(self, name)}")
        if self.fixed_point_check < 0:
            raise ValueError(f"option fixed_point_check must be >= 0, got {self.fixed_point_check}")
        if not 0.0 <= self.unfixed_share < 1.0:
            raise ValueError(f"option unfixed_share must be in [0, 1), got {self.unfixed_share}")
        if self.lo_matches != 0 and self.lo_matches < 16:
            raise ValueError(f"option lo_matches must be 0 (all) or >= 16, got {self.lo_matches}")
        for name in ("line_distance", "line_threshold", "sample_plane_factor", "race_pool_ratio"):
            if getattr(self, name) <= 0:
                raise ValueError(f"option {name} must be positive, got {getattr(self, name)}")
        if self.triple not in TRIPLES:
            raise ValueError(f"triple must be one of {TRIPLES}, got {self.triple!r}")
        if self.race_pool not in RACE_POOLS:
            raise ValueError(f"race_pool must be one of {RACE_POOLS}, got {self.race_pool!r}")
        if self.lo not in LO_SCHEMES:
            raise ValueError(f"lo must be one of {tuple(LO_SCHEMES)}, got {self.lo!r}")

    @classmethod
    def from_kwargs(cls, base: EstimatorOptions | None = None, **kwargs: Any) -> EstimatorOptions:
        """``base`` (default: the defaults) with the named fields replaced."""
        known = [f.name for f in fields(cls)]
        unknown = set(kwargs) - set(known)
        if unknown:
            raise ValueError(f"unknown options {sorted(unknown)}; known: {sorted(known)}")
        return replace(base or cls(), **kwargs)

    def sampling(self) -> SamplingOptions:
        """PROSAC / SPRT / bail-out options of the RANSAC loops."""
        return SamplingOptions(prosac=self.prosac, sprt=self.sprt, bailout=self.bailout)

    def line_search(self) -> LineSearchOptions:
        """Options of the line-pair search (two pairs beyond those that race, as spares)."""
        return LineSearchOptions(
            width=self.hough_width,
            min_votes=self.hough_min_votes,
            distance=self.line_distance,
            hough_points=self.hough_points,
            max_pairs=self.max_line_pairs + 2,
        )


_DEFAULTS = EstimatorOptions()


def _validate_points(pts1: Any, pts2: Any, min_points: int) -> tuple[np.ndarray, np.ndarray]:
    p1 = np.ascontiguousarray(pts1, dtype=np.float64)
    p2 = np.ascontiguousarray(pts2, dtype=np.float64)
    for name, p in (("pts1", p1), ("pts2", p2)):
        if p.ndim != 2 or p.shape[1] != 2:
            raise ValueError(f"{name} must have shape (N, 2), got {p.shape}")
    if p1.shape != p2.shape:
        raise ValueError(f"pts1 and pts2 must have the same shape, got {p1.shape} and {p2.shape}")
    if p1.shape[0] < min_points:
        raise ValueError(f"need at least {min_points} correspondences, got {p1.shape[0]}")
    n_bad, first_bad = _count_nonfinite(p1, p2)
    if n_bad:
        raise ValueError(f"{n_bad} correspondences contain NaN or inf (first at index {first_bad})")
    n_same, i, j = _count_duplicates(p1, p2)
    if n_same:
        raise ValueError(
            f"{n_same} duplicate correspondences (e.g. the matches at indices {i} and "
            f"{j} are identical); remove duplicates first"
        )
    return p1, p2


def _validate_size(size: Any, name: str) -> tuple[float, float]:
    if size is None:
        raise ValueError(f"{name} is required: (width, height) in pixels")
    try:
        w, h = (float(v) for v in size)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be (width, height), got {size!r}") from exc
    if not (np.isfinite(w) and np.isfinite(h) and w > 0 and h > 0):
        raise ValueError(f"{name} must be positive and finite, got {size!r}")
    return w, h


@numba.njit(cache=True, nogil=True)
def _count_nonfinite(p1: np.ndarray, p2: np.ndarray) -> tuple[int, int]:
    """(number of rows of (N, 2) p1 / p2 with a NaN or inf, index of the first such row or -1)."""
    count, first = 0, -1
    for i in range(p1.shape[0]):
        if not (
            np.isfinite(p1[i, 0])
            and np.isfinite(p1[i, 1])
            and np.isfinite(p2[i, 0])
            and np.isfinite(p2[i, 1])
        ):
            count += 1
            if first < 0:
                first = i
    return count, first


@numba.njit(cache=True, nogil=True)
def _count_duplicates(p1: np.ndarray, p2: np.ndarray) -> tuple[int, int, int]:
    """(rows equal to an earlier row, and the first such pair (i < j) or (-1, -1)).

    Rows are (p1[i], p2[i]); sorted by p1's u, equal rows sit in runs of equal u.
    """
    n = p1.shape[0]
    order = np.argsort(p1[:, 0])
    count, fi, fj = 0, -1, -1
    start = 0
    while start < n:
        end = start + 1
        while end < n and p1[order[end], 0] == p1[order[start], 0]:
            end += 1
        for a in range(start + 1, end):  # is row order[a] equal to an earlier one in the run?
            ia = order[a]
            for b in range(start, a):
                ib = order[b]
                if p1[ia, 1] == p1[ib, 1] and p2[ia, 0] == p2[ib, 0] and p2[ia, 1] == p2[ib, 1]:
                    count += 1
                    if fi < 0:
                        fi, fj = min(ia, ib), max(ia, ib)
                    break
        start = end
    return count, fi, fj


@numba.njit(cache=True, nogil=True)
def _principal_scatter(p: np.ndarray) -> tuple[float, float]:
    """(small, large) eigenvalues of the 2x2 scatter matrix (sum of outer products about the
    mean, px^2) of (N, 2) points."""
    n = p.shape[0]
    mu, mv = p[:, 0].mean(), p[:, 1].mean()
    a = b = c = 0.0
    for i in range(n):
        du, dv = p[i, 0] - mu, p[i, 1] - mv
        a += du * du
        b += du * dv
        c += dv * dv
    big = 0.5 * (a + c) + np.sqrt(0.25 * (a - c) ** 2 + b * b)
    if big <= 0:
        return 0.0, 0.0
    return max(0.0, (a * c - b * b) / big), big  # det / big = the small eigenvalue


@numba.njit(cache=True, nogil=True)
def _spread_ratio(p: np.ndarray) -> float:
    """Smallest / largest eigenvalue of the 2x2 scatter matrix of (N, 2) points (0: collinear)."""
    small, big = _principal_scatter(p)
    return small / big if big > 0 else 0.0


@numba.njit(cache=True, nogil=True)
def _across_std(p: np.ndarray) -> float:
    """Standard deviation (px) of (N >= 2, 2) points across their principal axis."""
    small, _ = _principal_scatter(p)
    return np.sqrt(small / (p.shape[0] - 1))


@numba.njit(cache=True, nogil=True)
def _median_motion(p1: np.ndarray, p2: np.ndarray) -> float:
    """Median over correspondences of ||p2 - p1|| (px)."""
    d = np.empty(p1.shape[0])
    for i in range(p1.shape[0]):
        d[i] = np.hypot(p2[i, 0] - p1[i, 0], p2[i, 1] - p1[i, 1])
    return np.median(d)


def _degeneracy(p1: np.ndarray, p2: np.ndarray, threshold: float) -> str | None:
    """A reason why no F can be determined from these points, or None."""
    for name, p in (("image 1", p1), ("image 2", p2)):
        if _spread_ratio(p) <= 1e-12:
            return f"degenerate: all points on one line in {name}"
    if _median_motion(p1, p2) < 0.1 * threshold:
        return "degenerate: no motion (points do not move between the images)"
    return None


def _line_band_status(q1: np.ndarray, q2: np.ndarray, threshold: float) -> str | None:
    """A reason when the inliers (K, 2) of either image lie in a band around one line.

    Matches within a couple of pixels of one image line fix only the line pair's share of F
    (3 of its 7 degrees of freedom, paper Sec. 3); the rest is fitted to noise. The band is the
    standard deviation across the points' principal axis, compared with 2 x ``threshold``.
    """
    for name, q in (("image 1", q1), ("image 2", q2)):
        if len(q) < 2:
            continue
        across = _across_std(np.ascontiguousarray(q))
        if across < 2.0 * threshold:
            return (
                f"degenerate: the {len(q)} inliers lie along one line in {name} "
                f"({across:.1f} px across it)"
            )
    return None


def _triples(fit: LineHomographyFit, p1: np.ndarray, p2: np.ndarray, kind: str):
    """The fixed line correspondences of stage 2.

    ``raw``: the H_e inliers at min, median and max t; ``synthesized``: exact correspondences
    from the refined H_e at those t; ``all``: every H_e inlier (a least-squares block).
    """
    inl = fit.inliers
    if kind == "all":
        return p1[inl], p2[inl]
    t = line_parameter(p1[inl], fit.ctrl1)
    order = np.argsort(t)
    pick = inl[order[[0, len(order) // 2, -1]]]
    if kind == "synthesized":
        return fit.map_points(t[order[[0, len(order) // 2, -1]]])
    return p1[pick], p2[pick]


def estimate_fundamental(
    pts1: Any,
    pts2: Any,
    image_size1: Any,
    image_size2: Any = None,
    method: str = DEFAULT_METHOD,
    threshold: float = 1.0,
    confidence: float = 0.99,
    seed: int | None = None,
    options: EstimatorOptions | None = None,
    **kwargs: Any,
) -> Estimate:
    """Estimate F (x2^T F x1 = 0) from putative matches with the separable method or a baseline.

    Args:
        pts1, pts2: (N, 2) pixel coordinates in image 1 and 2, best matches first if known.
        image_size1, image_size2: (width, height) in px; image_size2 defaults to image_size1.
        method: one of :data:`METHODS`.
        threshold: inlier threshold, px of symmetric epipolar distance. The LMedS methods
            (``*-lmeds``, ``lmeds7``, ``lmeds8``) do not use it to score, select or mark inliers
            (they use their robust scale, ``Estimate.scale``); for them it only serves the
            degeneracy checks and the breakdown check (see the module docstring).
        confidence: RANSAC confidence for adaptive termination F(k, r).
        seed: seed of the ``numpy.random.Generator`` behind every random choice.
        options: an :class:`EstimatorOptions` (default: its defaults).
        **kwargs: fields of :class:`EstimatorOptions` replacing those of ``options``
            (``max_samples=300, hough_width=384``, ...).
    Raises:
        ValueError: unknown method or option, malformed points or sizes, too few points.
    """
    t_start = time.perf_counter()
    if method not in _METHODS:
        raise ValueError(f"unknown method {method!r}; expected one of {METHODS}")
    if options is not None and not isinstance(options, EstimatorOptions):
        raise ValueError(f"options must be an EstimatorOptions, got {type(options).__name__}")
    opt = EstimatorOptions.from_kwargs(options, **kwargs) if kwargs else options or _DEFAULTS
    if not (np.isfinite(threshold) and threshold > 0):
        raise ValueError(f"threshold must be positive, got {threshold}")
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must be in (0, 1), got {confidence}")
    separable, solver, scoring = _METHODS[method]
    size1 = _validate_size(image_size1, "image_size1")
    size2 = _validate_size(image_size1 if image_size2 is None else image_size2, "image_size2")
    p1, p2 = _validate_points(pts1, pts2, 7 if solver == "seven" else 8)
    rng = np.random.default_rng(seed)
    est = Estimate(F=None, inliers=np.zeros(len(p1), dtype=bool), method=method)
    reason = _degeneracy(p1, p2, threshold)
    if reason is None:
        data = Correspondences.from_pixels(p1, p2)
        budget = Budget(sample_cap(opt.max_samples, len(data)))
        problem = _Problem(data, solver, scoring, threshold, confidence, opt, rng, budget)
        if separable:
            result = _separable(problem, est, size1, size2)
        else:
            t2 = time.perf_counter()
            result = problem.standard()
            est.stage2_hypotheses = result.hypotheses
            est.timings_ms["stage2"] = 1e3 * (time.perf_counter() - t2)
        est.hypotheses = est.stage1_hypotheses + est.stage2_hypotheses
        est.samples = budget.used
        if result.model is None:
            reason = "no model: every sample was degenerate"
        else:
            _finish(problem, est, result.model)
    if reason is not None:
        est.set_status(StatusCode.DEGENERATE, reason)
    est.timings_ms["total"] = 1e3 * (time.perf_counter() - t_start)
    return est


@dataclass
class _Problem:
    """What every step of one estimate shares: the matches, the method's solver and scoring,
    the thresholds, the options and the random generator."""

    data: Correspondences
    solver: str
    scoring: str
    threshold: float
    confidence: float
    opt: EstimatorOptions
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
        k = self.opt.lo_matches
        return self.data if k == 0 else self.data.spread(k)

    @property
    def model_points(self) -> int:
        return 7 if self.solver == "seven" else 8

    def min_samples(self, k: int) -> int:
        """Samples drawn at least: LMedS F(k, 0.5) (see the module docstring), else 1."""
        if not self.lmeds:
            return 1
        return min(ransac_trials(k, 0.5, self.confidence), self.budget.limit)

    def whole(self, race_share: float = 1.0) -> FundamentalProblem:
        """The problem over all matches (no fixed points), the ambiguous ones last in its pool;
        ``race_share``: its most share of a race's samples (``FundamentalProblem``)."""
        pool = None if self.ambiguous is None else self.pool_order(np.ones(len(self.data), bool))
        return FundamentalProblem(
            self.data, self.solver, self.threshold, self.scoring, pool=pool, scale=self.scale,
            lo=self.opt.lo, lo_data=self.lo_data, oriented=self.opt.oriented,
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
        arm = self.whole()
        sampling = replace(self.opt.sampling(), prosac_growth=max(1, self.budget.left()))
        return run_ransac(
            [arm], self.rng, self.confidence, self.budget.limit,
            min_samples=self.min_samples(arm.sample_size), initial=initial,
            budget=self.budget, sampling=sampling,
        )  # fmt: skip


def _separable(
    problem: _Problem, est: Estimate, size1: tuple[float, float], size2: tuple[float, float]
) -> RansacResult:
    """The separable method: line pairs, stage 1 on each as its arm joins the stage-2 race (with
    an arm without fixed points when the line pairs run out, option ``unfixed_share``), and
    standard RANSAC from the best model so far when no line pair helps or stage 2 hits its cap
    (a wrong fixed triple is the usual cause). Fills ``est``'s line-pair fields and timings."""
    d, opt = problem.data, problem.opt
    t0 = time.perf_counter()
    lopts = opt.line_search()
    pairs = find_line_pairs(d.pts1, d.pts2, size1, size2, lopts)
    t1 = time.perf_counter()
    est.timings_ms["lines"] = 1e3 * (t1 - t0)
    scales = (working_scale(size1, lopts.width), working_scale(size2, lopts.width))
    fits: list[LineHomographyFit | None] = []  # per stage-2 arm; None: the unfixed arm
    stage1_s = [0.0]

    def stage2_arms():
        """Stage 1 on the next line pair, run only when its stage-2 arm joins the race; with
        ``periodic_check``, arms of periodic line pairs are held back until the others joined
        and their matches are left out of the pools built from then on."""
        held: list[tuple[LineHomographyFit, FundamentalProblem]] = []
        for pair in pairs:
            if len(fits) >= opt.max_line_pairs:
                return
            t = time.perf_counter()
            got = _stage2_arm(problem, pair, size1, size2, scales, est)
            periodic = (
                got is not None and opt.periodic_check and _periodic(got[0], d.pts1, scales[0], opt)
            )
            stage1_s[0] += time.perf_counter() - t
            if periodic:
                est.periodic_line_pairs += 1
                held.append(got)
                if problem.ambiguous is None:
                    problem.ambiguous = np.zeros(len(d), dtype=bool)
                problem.ambiguous[pair.support] = True
            elif got is not None:
                fits.append(got[0])
                yield got[1]
        for fit, arm in held:
            if len(fits) >= opt.max_line_pairs:
                return
            fits.append(fit)
            yield arm
        if opt.unfixed_share > 0 and fits and len(fits) < opt.max_line_pairs:
            fits.append(None)
            yield problem.whole(race_share=opt.unfixed_share)

    result = run_ransac(
        stage2_arms(), problem.rng, problem.confidence, problem.budget.limit,
        race=RaceOptions(pool_rule=opt.race_pool, pool_ratio=opt.race_pool_ratio),
        budget=problem.budget,
        sampling=opt.sampling(),
        min_samples=problem.min_samples(problem.model_points - 3),
    )  # fmt: skip
    est.stage2_hypotheses += result.hypotheses
    if fits and result.leader >= 0 and fits[result.leader] is None:
        est.unfixed_lead = True
    elif fits and result.leader >= 0:
        best = fits[result.leader]
        est.line_pair = (tuple(best.pair.line1), tuple(best.pair.line2))
        est.line_inliers = best.inliers
        est.H_e = best.H
        est.control_points = (best.ctrl1, best.ctrl2)
    est.timings_ms["stage1"] = 1e3 * stage1_s[0]
    est.timings_ms["stage2"] = 1e3 * (time.perf_counter() - t1 - stage1_s[0])
    if fits and (result.converged or problem.budget.left() == 0):
        return result  # converged, or the budget is spent: no fallback beyond max_samples
    t3 = time.perf_counter()
    initial = None
    if fits and result.model is not None:
        initial = (result.model, result.cost, result.count)
    result = problem.standard(initial)
    est.fallback = True
    est.stage2_hypotheses += result.hypotheses
    est.timings_ms["fallback"] = 1e3 * (time.perf_counter() - t3)
    return result


def _stage2_arm(
    problem: _Problem,
    pair: LinePair,
    size1: tuple[float, float],
    size2: tuple[float, float],
    scales: tuple[float, float],
    est: Estimate,
) -> tuple[LineHomographyFit, FundamentalProblem] | None:
    """Stage 1 on ``pair``: (its fit, its stage-2 arm), or None when stage 1 fails or too few
    matches lie off the pair to sample from."""
    d, opt = problem.data, problem.opt
    left = problem.budget.left()
    if left < 2:
        return None
    fit, h = fit_line_homography(
        pair, d.pts1, d.pts2, size1, size2, scales[0], scales[1], problem.rng,
        threshold=opt.line_threshold, confidence=problem.confidence,
        min_inliers=opt.min_line_inliers, max_samples=min(STAGE1_MAX_SAMPLES, left // 2),
    )  # fmt: skip
    est.stage1_hypotheses += h
    problem.budget.spend(h)  # one H_e hypothesis per 3-point sample
    if fit is None:
        return None
    off_pair = np.ones(len(d), dtype=bool)
    off_pair[pair.support] = False
    if problem.ambiguous is not None:
        off_pair &= ~problem.ambiguous  # matches on a periodic line pair: not sampled
    pool = np.flatnonzero(off_pair)
    if len(pool) < (7 if problem.solver == "seven" else 8) - 3:
        return None
    f1, f2 = _triples(fit, d.pts1, d.pts2, opt.triple)
    tol = opt.sample_plane_factor * problem.threshold if opt.sample_plane_check else 0.0
    fixed_tol = 0.0
    if opt.triple != "all" and not problem.lmeds:
        fixed_tol = opt.fixed_point_check * problem.threshold
    return fit, FundamentalProblem(
        d,
        problem.solver,
        problem.threshold,
        problem.scoring,
        f1,
        f2,
        pool,
        scale=problem.scale,
        lo=opt.lo,
        plane_tol=tol,
        lo_data=problem.lo_data,
        fixed_tol=fixed_tol,
        oriented=opt.oriented,
    )


def _periodic(
    fit: LineHomographyFit, pts1: np.ndarray, scale1: float, opt: EstimatorOptions
) -> bool:
    """Whether the H_e inliers of ``fit`` on line 1 are a periodic point set: most of them on
    one projective arithmetic progression (``periodic.is_periodic`` in working px, tolerance
    PERIODIC_TOLERANCE). pts1: (N, 2) all matches in image 1, px; scale1: working px per px of
    image 1."""
    c = fit.ctrl1
    length = float(np.hypot(*(c[1] - c[0]))) * scale1
    return is_periodic(line_parameter(pts1[fit.inliers], c), length, PERIODIC_TOLERANCE)


def _finish(problem: _Problem, est: Estimate, F: np.ndarray) -> None:
    """Final model (refit, refinement, plane check), inliers and status into ``est``."""
    if problem.lmeds:
        _finish_lmeds(problem, est, F)
        return
    d, threshold = problem.data, problem.threshold
    t4 = time.perf_counter()
    # its own stream (spawned: the estimate's stream is not advanced), so switching it off
    # changes no other step's draws
    inner_rng = problem.rng.spawn(1)[0]
    F, scored = inner_sampling(F, problem.whole(), inner_rng, problem.opt.inner_samples)
    est.stage2_hypotheses += scored
    F, refits = _final_model(F, d, threshold, problem.opt.refine)
    est.stage2_hypotheses += refits  # final refits are scored against all matches too
    plane = None
    check = _plane_check(problem, est, F)
    if check is not None:
        F, plane = check.F, check.reason
    if problem.opt.final_polish and problem.opt.lo == "lm" and plane is None:
        off_plane = None
        if check is not None and check.H is not None:
            off_plane = transfer_error(check.H, d.pts1, d.pts2) >= PLANE_TOLERANCE * threshold
        F = normalize_fundamental(polish_final(F, d, threshold, off_plane))
    est.hypotheses = est.stage1_hypotheses + est.stage2_hypotheses
    est.F = F
    est.inliers = d.distances(F) < threshold
    est.timings_ms["refine"] = 1e3 * (time.perf_counter() - t4)
    _final_status(problem, est, plane)


def _plane_check(problem: _Problem, est: Estimate, F: np.ndarray):
    """The dominant-plane check of ``F`` (``degeneracy.plane_and_parallax``) when the options ask
    for it, its candidates counted in ``est``; None when it is off."""
    if not problem.opt.plane_check:
        return None
    d = problem.data
    check = plane_and_parallax(
        F, d.pts1, d.pts2, problem.threshold, problem.rng,
        adaptive=problem.opt.plane_check_adaptive,
    )  # fmt: skip
    est.stage2_hypotheses += check.candidates
    opt = problem.opt
    if opt.shifted_plane_check and check.planar and not check.replaced and check.reason is None:
        check = _periodic_plane_check(problem, est, check)
    return check


def _periodic_plane_check(problem: _Problem, est: Estimate, check: PlaneCheck) -> PlaneCheck:
    """The plane check again without the matches on a period-shifted copy of its plane
    (``periodic.shifted_plane_copy``): they lie off the plane but only say that F's epipole is
    the vanishing point of the texture's period, so they must not count as parallax. Returns
    ``check`` when there is no such copy, else the check on the other matches, where F is
    always challenged by plane-and-parallax candidates (a wrong F through the plane and its
    copy can gather some chance support off them)."""
    d, threshold = problem.data, problem.threshold
    tol = PLANE_TOLERANCE * threshold  # the plane check's homography tolerance
    inl = d.distances(check.F) < threshold
    far = transfer_error(check.H, d.pts1, d.pts2) > 2.0 * tol  # its "clear parallax"
    shifted = shifted_plane_copy(check.H, d.pts1, d.pts2, inl & far, tol, problem.rng)
    if shifted is None and not check.accepted:
        # a copy F does not explain: F may still ignore the parallax (unless its support off
        # the plane is far above chance, when the plane check kept it without a challenge)
        shifted = shifted_plane_copy(
            check.H, d.pts1, d.pts2, far, tol, problem.rng, min_share=0.15, max_iterations=100
        )
    if shifted is None:
        return check
    keep = ~shifted
    p1, p2 = d.pts1[keep], d.pts2[keep]
    adaptive = problem.opt.plane_check_adaptive
    # F is challenged by plane-and-parallax candidates whatever its support off the plane
    # (min_excess beyond any count), then the kept or replaced F is checked as usual
    challenge = plane_and_parallax(
        check.F, p1, p2, threshold, problem.rng, adaptive=adaptive, min_excess=len(d) + 1
    )
    again = plane_and_parallax(challenge.F, p1, p2, threshold, problem.rng, adaptive=adaptive)
    est.stage2_hypotheses += challenge.candidates + again.candidates
    again.replaced = again.replaced or challenge.replaced
    return again


def _final_status(
    problem: _Problem, est: Estimate, plane: str | None, unreliable: str | None = None
) -> None:
    """``est.status`` from its final inliers: too few, inliers in a band around one line (the
    more specific reason when a plane holds them too: a band lies on many planes), the plane
    check's reason, ``unreliable`` (a method's own reason), or a consensus that random matches
    give as well (``est.log10_nfa`` >= ``MAX_LOG10_NFA``, :mod:`significance`); else left as it
    is. The significance test draws its random re-pairings from a stream of its own."""
    d, threshold = problem.data, problem.threshold
    k = est.num_inliers
    if k < 8:
        est.set_status(StatusCode.DEGENERATE, f"degenerate: only {k} inliers")
        return
    rng = problem.rng.spawn(1)[0]
    est.log10_nfa = consensus_log10_nfa(est.F, d, est.inliers, threshold, rng)
    chance = None
    if not est.log10_nfa < MAX_LOG10_NFA:
        chance = (
            f"not significant: {k} of {len(d)} matches within {threshold:g} px, as random "
            f"matches would give (log10 NFA {est.log10_nfa:+.1f})"
        )
    band = _line_band_status(d.pts1[est.inliers], d.pts2[est.inliers], threshold)
    for code, text in (
        (StatusCode.DEGENERATE, band or plane),
        (StatusCode.UNRELIABLE, unreliable),
        (StatusCode.NOT_SIGNIFICANT, chance),
    ):
        if text:
            est.set_status(code, text)
            return


def _final_model(
    F: np.ndarray, data: Correspondences, threshold: float, refine: bool
) -> tuple[np.ndarray, int]:
    """Refit on all inliers (normalised eight-point), optionally Sampson-refined, rank 2.

    Returns (F, number of refitted models scored). A refit replaces F only if it lowers the
    MSAC cost at ``threshold`` (see :func:`iterative_refit`).
    """
    fitted = iterative_refit(F, data, threshold, irls_iterations=2 if refine else 0)
    candidates = np.ascontiguousarray(np.stack([F, *fitted]))
    cost, _ = msac_kernel(candidates, data.X1, data.X2, threshold)
    return normalize_fundamental(candidates[int(np.argmin(cost))]), len(fitted)


def _median_sq(F: np.ndarray, data: Correspondences) -> np.ndarray:
    """Median squared symmetric epipolar distance (px^2) of (3, 3) or (K, 3, 3) models."""
    d = data.distances(np.ascontiguousarray(F))
    return np.median(d * d, axis=-1)


def _final_model_lmeds(
    F: np.ndarray, data: Correspondences, model_points: int, refine: bool
) -> tuple[np.ndarray, int]:
    """LMedS final model: F and its refits on its robust inliers (:func:`lmeds_refit`, Sampson
    IRLS with ``refine``), the lowest median kept. Returns (F, number of refits scored)."""
    fitted = lmeds_refit(F, data, model_points, irls_iterations=2 if refine else 0)
    candidates = np.ascontiguousarray(np.stack([F, *fitted]))
    return normalize_fundamental(candidates[int(np.argmin(_median_sq(candidates, data)))]), len(
        fitted
    )


def _finish_lmeds(problem: _Problem, est: Estimate, F: np.ndarray) -> None:
    """:func:`_finish` of the LMedS methods: the final model by median, the plane check as a
    degeneracy test (``threshold``), inliers from the robust scale, the breakdown check."""
    d, threshold = problem.data, problem.threshold
    t4 = time.perf_counter()
    F, refits = _final_model_lmeds(F, d, problem.model_points, problem.opt.refine)
    est.stage2_hypotheses += refits
    plane = None
    check = _plane_check(problem, est, F)
    if check is not None:
        plane = check.reason
        if check.replaced:
            # the check found F without support off a dominant plane; its plane-and-parallax
            # model is taken only if it does not raise the median
            if _median_sq(check.F, d) <= _median_sq(F, d):
                F = check.F
            elif plane is None:
                plane = "degenerate: dominant plane (the least-median F has no support off it)"
    est.hypotheses = est.stage1_hypotheses + est.stage2_hypotheses
    est.F = F
    est.inliers, est.scale, _ = lmeds_final_inliers(d.distances(F), problem.model_points)
    est.timings_ms["refine"] = 1e3 * (time.perf_counter() - t4)
    unreliable = None
    if est.scale > threshold:
        unreliable = (
            f"unreliable: robust scale {est.scale:.2f} px exceeds the threshold {threshold:g} px "
            "(more than half of the matches are outliers, beyond LMedS's breakdown point, or "
            "the noise exceeds the threshold)"
        )
    _final_status(problem, est, plane, unreliable)
