"""Typed options of the fundamental-matrix side: sampling, local optimisation and checks.

Each part is a frozen dataclass whose values are converted to the field's type (``int``,
``float``, ``bool``; ``str`` for the Literal choices) and checked when it is made; bad values
raise ``ValueError``. :class:`~sepfm_ros.geometry.options.EstimatorOptions` composes them.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any, Literal, get_args

import numpy as np

from sepfm_ros.geometry.robust.options import SamplingOptions

__all__ = [
    "Checks",
    "LoScheme",
    "LocalOptimization",
    "Sampling",
    "Scoring",
    "Solver",
    "coerce_fields",
    "require_choice",
    "require_least",
    "require_positive",
]

#: minimal solver of a method: seven-point (each real root a model) or eight-point
Solver = Literal["seven", "eight"]
#: how a model is scored: MSAC (truncated quadratic at the threshold) or least median of squares
Scoring = Literal["msac", "lmeds"]
#: local optimisation inside RANSAC (:data:`~sepfm_ros.geometry.fundamental.problem.LO_SCHEMES`)
LoScheme = Literal["lm", "sampson", "plain"]

_KINDS: dict[str, type] = {"int": int, "float": float, "bool": bool}


def coerce_fields(part: Any) -> None:
    """Convert every field of the frozen dataclass ``part`` to its type in place (a Literal
    alias: ``str``); ``ValueError`` naming the option when a value does not convert or a float
    is not finite."""
    for f in fields(part):
        value = getattr(part, f.name)
        kind = _KINDS.get(str(f.type), str)
        try:
            converted = kind(value)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"option {f.name} must be {f.type}, got {value!r}") from exc
        if kind is float and not np.isfinite(converted):
            raise ValueError(f"option {f.name} must be finite, got {value!r}")
        object.__setattr__(part, f.name, converted)


def require_least(part: Any, least: dict[str, int]) -> None:
    """``ValueError`` when a named field of ``part`` is below its least value."""
    for name, low in least.items():
        if getattr(part, name) < low:
            raise ValueError(f"option {name} must be >= {low}, got {getattr(part, name)}")


def require_positive(part: Any, names: tuple[str, ...]) -> None:
    """``ValueError`` when a named field of ``part`` is not positive."""
    for name in names:
        if getattr(part, name) <= 0:
            raise ValueError(f"option {name} must be positive, got {getattr(part, name)}")


def require_choice(name: str, value: str, choices: Any) -> None:
    """``ValueError`` when ``value`` is not one of the Literal type ``choices``."""
    allowed = get_args(choices)
    if value not in allowed:
        raise ValueError(f"{name} must be one of {allowed}, got {value!r}")


@dataclass(frozen=True)
class Sampling:
    """How the samples of one estimate are drawn.

    Attributes:
        max_samples: cap on the samples of one estimate, shared by all its stages (the
            separable method's 3-point samples of stage 1, stage 2's racing arms and the
            fallback), so a separable method draws no more than a baseline may; 0 (default):
            :func:`~sepfm_ros.geometry.fundamental.task.sample_cap` of the number of matches.
        prosac: PROSAC sampling (best matches first) in every RANSAC loop.
        sprt: SPRT early rejection of minimal-sample models (Matas & Chum) in every loop.
        bailout: exact early rejection of minimal-sample models that cannot matter.
    """

    max_samples: int = 0
    prosac: bool = True
    sprt: bool = True
    bailout: bool = True

    def __post_init__(self) -> None:
        coerce_fields(self)
        require_least(self, {"max_samples": 0})

    def loop(self) -> SamplingOptions:
        """The robust loop's PROSAC / SPRT / bail-out options."""
        return SamplingOptions(prosac=self.prosac, sprt=self.sprt, bailout=self.bailout)


@dataclass(frozen=True)
class LocalOptimization:
    """Local optimisation inside RANSAC and of the final model.

    Attributes:
        lo: ``"lm"`` (Sampson-weighted refits from 3x the threshold down, then
            Levenberg-Marquardt on the truncated geometric error), ``"sampson"`` (the refits
            alone) or ``"plain"`` (least squares at 2x and 1x); see ``LO_SCHEMES``.
        lo_matches: local optimisation (refits and Levenberg-Marquardt; MSAC-scored methods,
            the ``-lmeds`` ones refit on all) fits on at most this many matches, taken evenly
            along the match order (``Correspondences.spread``; 0: on all); its models are
            scored on all matches, and the final model is refitted on all of them.
        inner_samples: inner sampling of the final model (LO-RANSAC's inner RANSAC, once per
            estimate): this many samples of 14 of its inliers are fitted by least squares, the
            best starts the refits, and a refit is kept if it lowers the MSAC cost at the
            threshold and not at the noise truncation. 0: off; not with LMedS.
        refine: Sampson (IRLS) refinement of the final model.
        final_polish: with ``lo="lm"``, the final model is refined once more by
            Levenberg-Marquardt (``nonlinear.polish_final``).
    """

    lo: LoScheme = "lm"
    lo_matches: int = 600
    inner_samples: int = 20
    refine: bool = True
    final_polish: bool = True

    def __post_init__(self) -> None:
        coerce_fields(self)
        require_least(self, {"inner_samples": 0})
        if self.lo_matches != 0 and self.lo_matches < 16:
            raise ValueError(f"option lo_matches must be 0 (all) or >= 16, got {self.lo_matches}")
        require_choice("lo", self.lo, LoScheme)


@dataclass(frozen=True)
class Checks:
    """Checks of samples and of the final model.

    Attributes:
        plane_check: DEGENSAC-style plane-and-parallax check of the final F (degeneracy.py).
        plane_check_adaptive: the plane check tries off-plane pairs until F(2, w) were tried
            (w: the best candidate's off-plane inlier share) instead of all 300.
        shifted_plane_check: the final plane check discounts matches on a period-shifted copy
            of the plane (``shifted_plane.shifted_plane_copy``; a chessboard matched one square
            off) and then challenges F with plane-and-parallax candidates.
        oriented: every RANSAC stage drops, before scoring, the models for which the
            sample's own matches (fixed line points included) break the oriented epipolar
            constraint (``solvers/orientation.py``). Off by default (docs/design.md).
    """

    plane_check: bool = True
    plane_check_adaptive: bool = True
    shifted_plane_check: bool = True
    oriented: bool = False

    def __post_init__(self) -> None:
        coerce_fields(self)
