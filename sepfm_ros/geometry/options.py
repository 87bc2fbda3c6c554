"""Options of :func:`~sepfm_ros.geometry.estimate_fundamental` beyond method, threshold,
confidence and seed: small typed parts composed behind one flat constructor.

=================  ==========================================================================
part               fields
=================  ==========================================================================
``sampler``        :class:`~sepfm_ros.geometry.fundamental.options.Sampling`: max_samples,
                   prosac, sprt, bailout
``local``          :class:`~sepfm_ros.geometry.fundamental.options.LocalOptimization`: lo,
                   lo_matches, inner_samples, refine, final_polish
``checks``         :class:`~sepfm_ros.geometry.fundamental.options.Checks`: plane_check,
                   plane_check_adaptive, shifted_plane_check, oriented
``lines``          :class:`~sepfm_ros.geometry.separable.options.Lines`: hough_width,
                   line_distance, max_line_pairs, line_threshold, min_line_inliers,
                   periodic_check
``fixed``          :class:`~sepfm_ros.geometry.separable.options.FixedPoints`: triple,
                   fixed_point_check, sample_plane_check
``race``           :class:`~sepfm_ros.geometry.separable.options.Race`: race_pool,
                   race_pool_ratio, unfixed_share
=================  ==========================================================================
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

from sepfm_ros.geometry.fundamental.options import (
    Checks,
    LocalOptimization,
    Sampling,
    Scoring,
    Solver,
)
from sepfm_ros.geometry.robust.options import SamplingOptions
from sepfm_ros.geometry.separable.options import FixedPoints, Lines, LineSearchOptions, Race

__all__ = ["DEFAULT_METHOD", "METHODS", "METHOD_SPECS", "EstimatorOptions"]

#: method -> (separable?, minimal solver, scoring)
METHOD_SPECS: dict[str, tuple[bool, Solver, Scoring]] = {
    "sep4": (True, "seven", "msac"),
    "sep5": (True, "eight", "msac"),
    "sep4-lmeds": (True, "seven", "lmeds"),
    "sep5-lmeds": (True, "eight", "lmeds"),
    "ransac7": (False, "seven", "msac"),
    "ransac8": (False, "eight", "msac"),
    "lmeds7": (False, "seven", "lmeds"),
    "lmeds8": (False, "eight", "lmeds"),
}
METHODS = tuple(METHOD_SPECS)
#: The method of the node, ``process``, ``eval``'s comparisons and the library when none is named:
#: the one that measures best (docs/benchmarks.md, ablation and hard-set sections).
DEFAULT_METHOD = "sep4"

#: part attribute -> its type, in the order of the table above
_PARTS: dict[str, type] = {
    "sampler": Sampling,
    "local": LocalOptimization,
    "checks": Checks,
    "lines": Lines,
    "fixed": FixedPoints,
    "race": Race,
}
#: flat option name -> the part attribute that holds it
_OWNER: dict[str, str] = {f.name: part for part, kind in _PARTS.items() for f in fields(kind)}


@dataclass(frozen=True, init=False)
class EstimatorOptions:
    """Options of :func:`~sepfm_ros.geometry.estimate_fundamental`, made from flat keywords
    (``EstimatorOptions(max_samples=300, triple="all")``) and read flat (``opt.max_samples``)
    or by part (``opt.sampler.max_samples``). Values are converted to the field's type and
    checked when the object is made; bad or unknown values raise ``ValueError``. The fields and
    what they do: the part classes of the module table."""

    sampler: Sampling
    local: LocalOptimization
    checks: Checks
    lines: Lines
    fixed: FixedPoints
    race: Race

    def __init__(self, **options: Any) -> None:
        unknown = set(options) - set(_OWNER)
        if unknown:
            raise ValueError(f"unknown options {sorted(unknown)}; known: {sorted(_OWNER)}")
        for part, kind in _PARTS.items():
            mine = {name: value for name, value in options.items() if _OWNER[name] == part}
            object.__setattr__(self, part, kind(**mine))

    def __getattr__(self, name: str) -> Any:
        """A flat option's value (``opt.max_samples`` is ``opt.sampler.max_samples``)."""
        part = _OWNER.get(name)
        if part is None:
            raise AttributeError(f"{type(self).__name__} has no option {name!r}")
        return getattr(object.__getattribute__(self, part), name)

    def flat(self) -> dict[str, Any]:
        """Every option by its flat name."""
        return {name: getattr(getattr(self, part), name) for name, part in _OWNER.items()}

    @classmethod
    def from_kwargs(cls, base: EstimatorOptions | None = None, **kwargs: Any) -> EstimatorOptions:
        """``base`` (default: the defaults) with the named fields replaced."""
        return cls(**{**(base or cls()).flat(), **kwargs})

    def sampling(self) -> SamplingOptions:
        """PROSAC / SPRT / bail-out options of the RANSAC loops."""
        return self.sampler.loop()

    def line_search(self) -> LineSearchOptions:
        """Options of the line-pair search (two pairs beyond those that race, as spares)."""
        return self.lines.search()
