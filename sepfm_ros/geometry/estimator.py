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
  (:func:`~sepfm_ros.geometry.fundamental.refine.lmeds_refit`);
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
from typing import Any

import numpy as np

from sepfm_ros.geometry.estimate import Estimate, StatusCode
from sepfm_ros.geometry.fundamental.checks import input_degeneracy, validate_points, validate_size
from sepfm_ros.geometry.fundamental.correspondences import Correspondences
from sepfm_ros.geometry.fundamental.final import finish
from sepfm_ros.geometry.fundamental.task import FundamentalTask, sample_cap
from sepfm_ros.geometry.options import DEFAULT_METHOD, METHOD_SPECS, METHODS, EstimatorOptions
from sepfm_ros.geometry.robust.loop import Budget
from sepfm_ros.geometry.separable.method import SeparableOptions, separable

__all__ = ["DEFAULT_METHOD", "METHODS", "estimate_fundamental"]

_DEFAULTS = EstimatorOptions()


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
    if method not in METHOD_SPECS:
        raise ValueError(f"unknown method {method!r}; expected one of {METHODS}")
    if options is not None and not isinstance(options, EstimatorOptions):
        raise ValueError(f"options must be an EstimatorOptions, got {type(options).__name__}")
    opt = EstimatorOptions.from_kwargs(options, **kwargs) if kwargs else options or _DEFAULTS
    if not (np.isfinite(threshold) and threshold > 0):
        raise ValueError(f"threshold must be positive, got {threshold}")
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must be in (0, 1), got {confidence}")
    solver = METHOD_SPECS[method][1]
    size1 = validate_size(image_size1, "image_size1")
    size2 = validate_size(image_size1 if image_size2 is None else image_size2, "image_size2")
    p1, p2 = validate_points(pts1, pts2, 7 if solver == "seven" else 8)
    est = Estimate(F=None, inliers=np.zeros(len(p1), dtype=bool), method=method)
    reason = input_degeneracy(p1, p2, threshold)
    if reason is None:
        args = (p1, p2, size1, size2, method, threshold, confidence, seed)
        reason = _estimate(*args, opt, est)
        if est.line_search_skipped and (reason is not None or est.code == StatusCode.DEGENERATE):
            # the escape's standard RANSAC found no F or a degenerate one (a dominant plane
            # shows a high inlier ratio to the probe): the line search gets its turn, as
            # without the escape (same seed); the work of the first try counts
            first = est
            est = Estimate(F=None, inliers=np.zeros(len(p1), dtype=bool), method=method)
            no_escape = EstimatorOptions.from_kwargs(opt, line_search_escape=False)
            reason = _estimate(*args, no_escape, est)
            est.stage2_hypotheses += first.stage2_hypotheses
            est.hypotheses += first.hypotheses
            est.samples += first.samples
            est.timings_ms["escape"] = first.timings_ms.get("stage2", 0.0)
    if reason is not None:
        est.set_status(StatusCode.DEGENERATE, reason)
    est.timings_ms["total"] = 1e3 * (time.perf_counter() - t_start)
    return est


def _estimate(
    p1: np.ndarray,
    p2: np.ndarray,
    size1: tuple[float, float],
    size2: tuple[float, float],
    method: str,
    threshold: float,
    confidence: float,
    seed: int | None,
    opt: EstimatorOptions,
    est: Estimate,
) -> str | None:
    """One estimate of F from validated (N, 2) pixels into ``est`` (a fresh generator from
    ``seed``); the reason when every sample was degenerate, else None."""
    is_separable, solver, scoring = METHOD_SPECS[method]
    data = Correspondences.from_pixels(p1, p2)
    budget = Budget(sample_cap(opt.sampler.max_samples, len(data)))
    problem = FundamentalTask(
        data, solver, scoring, threshold, confidence, opt.sampler, opt.local, opt.checks,
        np.random.default_rng(seed), budget,
    )  # fmt: skip
    if is_separable:
        parts = SeparableOptions(opt.lines, opt.fixed, opt.race)
        result = separable(problem, parts, est, size1, size2)
    else:
        t2 = time.perf_counter()
        result = problem.standard()
        est.stage2_hypotheses = result.hypotheses
        est.timings_ms["stage2"] = 1e3 * (time.perf_counter() - t2)
    est.hypotheses = est.stage1_hypotheses + est.stage2_hypotheses
    est.samples = budget.used
    if result.model is None:
        return "no model: every sample was degenerate"
    finish(problem, est, result.model)
    return None
