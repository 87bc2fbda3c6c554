"""Typed options of the separable method: the line-pair search and stage 1, the fixed points of
stage 2, and the race of its arms (see :class:`~sepfm_ros.geometry.options.EstimatorOptions`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from sepfm_ros.geometry.fundamental.options import (
    coerce_fields,
    require_choice,
    require_least,
    require_positive,
)
from sepfm_ros.geometry.robust.options import PoolRule

#: The line search's cost in F hypotheses (one seven-point model solved and scored on all
#: matches, with the loop's share of local optimisation): its median ms per pair over
#: ransac7's median ms per hypothesis of its loop (``timings_ms["stage2"]`` / hypotheses), both
#: from ``benchmarks/bench_ablation.py`` ("line search in hypothesis-equivalents"): 0.62 ms over
#: 14.5 us = 43 on the shared pairs (SIFT 0.95), whose clean pairs sit near the break-even ratio
#: where the figure matters; about 400 on the line-rich pairs, whose hard pairs' hypotheses are
#: mostly cut short by the SPRT and whose inlier ratios are far below the break-even (at w = 0.5
#: the line search pays up to 739). Defined here, where the escape (``separable.escape``) reads
#: it, so that the node's parameter table imports no numba.
LINE_SEARCH_HYPOTHESES = 43.0


@dataclass(frozen=True)
class LineSearchOptions:
    """Parameters of the line-pair search.

    width: working resolution (px) of the binary images; points are scaled by width / image width.
    min_votes: minimum Hough votes of a line (the paper's "at least four correspondences").
    distance: C, the point-to-line incidence distance, in px at the working resolution.
    hough_points: how many of the best-ranked matches are drawn into the binary images (all
        matches are then tested for incidence). Drawing every match makes Hough find thousands of
        spurious lines on textured scenes.
    max_lines: most lines kept per image (strongest first).
    max_pairs: most line pairs returned (best joint count first, overlapping supports suppressed).
    """

    width: int = 512
    min_votes: int = 4
    distance: float = 1.5
    hough_points: int = 300
    max_lines: int = 80
    max_pairs: int = 6


__all__ = [
    "HOUGH_MIN_VOTES",
    "HOUGH_POINTS",
    "SAMPLE_PLANE_FACTOR",
    "FixedPoints",
    "LineSearchOptions",
    "Lines",
    "Race",
    "Triple",
]

#: the fixed line correspondences of stage 2: sample points, points synthesized from the refined
#: H_e, or every H_e inlier (a least-squares block)
Triple = Literal["raw", "synthesized", "all"]
#: least votes of a Hough line of the line search
HOUGH_MIN_VOTES = 4
#: best matches drawn into the binary images of the line search
HOUGH_POINTS = 300
#: tolerance of the in-sample plane check on the homography's transfer error, times the threshold
SAMPLE_PLANE_FACTOR = 2.0


@dataclass(frozen=True)
class Lines:
    """The line-pair search and stage 1 (H_e on a line pair).

    Attributes:
        hough_width: working resolution of the line search, px.
        line_distance: C, the point-line incidence distance, working px (in image px
            C x image width / ``hough_width``: 7.3 px at KITTI's 1241 px, 3.75 px at 640 px).
        max_line_pairs: line pairs whose stage-2 arms race.
        line_threshold: T1, the H_e inlier threshold of stage 1, working px. T1 and C scale
            with the image width, not with F's threshold (docs/benchmarks.md, section "Race
            pooling and line thresholds"; test_plane_sampling.py).
        min_line_inliers: line correspondences that must agree with H_e (>= 3).
        periodic_check: a line pair whose H_e inliers on line 1 lie on one projective
            arithmetic progression (``periodic.is_periodic`` at 2 T1) is ambiguous: its
            stage-2 arm joins the race only after those of the other line pairs, and its
            matches are not sampled by the arms built after it was found and come last in the
            fallback's PROSAC order. Off by default (docs/design.md, repetitive structure).
        line_search_escape: the paper's escape (``separable.escape``): the first PROSAC
            samples of standard RANSAC probe the inlier ratio, and when F(3, r) + F(k - 3, r)
            plus the line search's cost is not below F(k, r), standard RANSAC goes on from the
            probe and the line search is skipped (``Estimate.line_search_skipped``). Not
            applied to the LMedS methods.
        line_search_cost: the line search's cost in F hypotheses that the escape weighs
            (default :data:`LINE_SEARCH_HYPOTHESES`, measured by
            ``benchmarks/bench_ablation.py``).
    """

    hough_width: int = 512
    line_distance: float = 3.0
    max_line_pairs: int = 4
    line_threshold: float = 1.0
    min_line_inliers: int = 4
    periodic_check: bool = False
    line_search_escape: bool = True
    line_search_cost: float = LINE_SEARCH_HYPOTHESES

    def __post_init__(self) -> None:
        coerce_fields(self)
        require_least(self, {"hough_width": 1, "max_line_pairs": 1, "min_line_inliers": 3})
        require_positive(self, ("line_distance", "line_threshold"))
        if not self.line_search_cost >= 0:  # NaN too
            raise ValueError(f"option line_search_cost must be >= 0, got {self.line_search_cost}")

    def search(self) -> LineSearchOptions:
        """Options of the line-pair search (two pairs beyond those that race, as spares)."""
        return LineSearchOptions(
            width=self.hough_width,
            min_votes=HOUGH_MIN_VOTES,
            distance=self.line_distance,
            hough_points=HOUGH_POINTS,
            max_pairs=self.max_line_pairs + 2,
        )


@dataclass(frozen=True)
class FixedPoints:
    """Stage 2's fixed line correspondences and the checks on them.

    Attributes:
        triple: ``"raw"`` sample points, ``"synthesized"`` from the refined H_e, or ``"all"``
            H_e inliers as the fixed line correspondences of stage 2.
        fixed_point_check: a stage-2 arm whose fixed line correspondences are not all within
            ``fixed_point_check`` times the threshold of the best model so far is dropped, and
            its samples no longer count toward the F(k, r) stop (docs/design.md, fixed-point
            check). 0: off; not applied with ``triple="all"`` or with the LMedS methods.
        sample_plane_check: stage 2 rejects, before solving, a sample two of whose points lie
            on one plane with the fixed line points (``line_planes.py``, tolerance
            ``SAMPLE_PLANE_FACTOR`` times the threshold); it still counts as drawn. Off by
            default: on real pairs it lowered sep4/sep5's F-score.
    """

    triple: Triple = "raw"
    fixed_point_check: float = 1.5
    sample_plane_check: bool = False

    def __post_init__(self) -> None:
        coerce_fields(self)
        if self.fixed_point_check < 0:
            raise ValueError(f"option fixed_point_check must be >= 0, got {self.fixed_point_check}")
        require_choice("triple", self.triple, Triple)


@dataclass(frozen=True)
class Race:
    """How stage 2's arms race (``robust.race``).

    Attributes:
        race_pool, race_pool_ratio: which racing stage-2 arms' samples count toward the pooled
            F(k, r) stop besides the leader's: ``"support"``, arms with at least
            ``race_pool_ratio`` of the best model's inlier count; ``"model"``, arms whose best
            model has at least ``race_pool_ratio`` of the best model's inliers among its own
            (``RaceOptions.pool_rule`` / ``pool_ratio``).
        unfixed_share: when fewer than ``max_line_pairs`` line pairs give a stage-2 arm, an arm
            without fixed points (k = 7 or 8) joins the race after them and draws at most this
            share of stage 2's samples while another arm is active (docs/design.md, unfixed
            arm). 0: off.
    """

    race_pool: PoolRule = "support"
    race_pool_ratio: float = 0.8
    unfixed_share: float = 0.25

    def __post_init__(self) -> None:
        coerce_fields(self)
        if not 0.0 <= self.unfixed_share < 1.0:
            raise ValueError(f"option unfixed_share must be in [0, 1), got {self.unfixed_share}")
        require_positive(self, ("race_pool_ratio",))
        require_choice("race_pool", self.race_pool, PoolRule)
