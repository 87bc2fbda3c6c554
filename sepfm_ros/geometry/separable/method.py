"""The separable two-stage method (paper Sec. 5): the escape to standard RANSAC where the line
search cannot pay for itself (``separable.escape``), line pairs, stage 1 (H_e on each line pair,
as its arm joins), stage 2 (the race of 3 fixed + 4 or 5 sampled arms) and the fallback to
standard RANSAC from the best model so far."""

from __future__ import annotations

import time
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from sepfm_ros.geometry.estimate import Estimate
from sepfm_ros.geometry.fundamental.compiled_loop import CompiledLoop
from sepfm_ros.geometry.fundamental.problem import FundamentalProblem
from sepfm_ros.geometry.fundamental.task import FundamentalTask
from sepfm_ros.geometry.robust.loop import RansacResult, run_ransac
from sepfm_ros.geometry.robust.options import RaceOptions
from sepfm_ros.geometry.separable.escape import (
    PROBE_LO_GAIN,
    PROBE_SAMPLES,
    copy_generator,
    line_search_pays,
)
from sepfm_ros.geometry.separable.line_pairs import (
    LinePair,
    find_line_pairs,
    line_parameter,
    working_scale,
)
from sepfm_ros.geometry.separable.options import (
    SAMPLE_PLANE_FACTOR,
    FixedPoints,
    Lines,
    Race,
    Triple,
)
from sepfm_ros.geometry.separable.periodic import is_periodic
from sepfm_ros.geometry.separable.stage1 import LineHomographyFit, fit_line_homography
from sepfm_ros.geometry.separable.stage2 import Stage2Problem

__all__ = ["SeparableOptions", "separable"]

#: Most 3-point samples of stage 1 per line pair and control-point orientation (two orientations).
STAGE1_MAX_SAMPLES = 200
#: Tolerance (working px) of the periodic line-pair test (``periodic_check``): a point is on a
#: progression's node within min(this, 0.15 of the local period).
PERIODIC_TOLERANCE = 1.0


@dataclass(frozen=True)
class SeparableOptions:
    """The separable method's parts of :class:`~sepfm_ros.geometry.options.EstimatorOptions`."""

    lines: Lines
    fixed: FixedPoints
    race: Race


def _triples(
    fit: LineHomographyFit, p1: np.ndarray, p2: np.ndarray, kind: Triple
) -> tuple[np.ndarray, np.ndarray]:
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


def separable(
    problem: FundamentalTask,
    options: SeparableOptions,
    est: Estimate,
    size1: tuple[float, float],
    size2: tuple[float, float],
) -> RansacResult:
    """The separable method: line pairs, stage 1 on each as its arm joins the stage-2 race (with
    an arm without fixed points when the line pairs run out, option ``unfixed_share``), and
    standard RANSAC from the best model so far when no line pair helps or stage 2 hits its cap
    (a wrong fixed triple is the usual cause). Fills ``est``'s line-pair fields and timings."""
    d, opt = problem.data, options
    t0 = time.perf_counter()
    if opt.lines.line_search_escape and not problem.lmeds:
        escaped = _escape(problem, opt.lines.line_search_cost, est)
        if escaped is not None:
            return escaped
        t0 = time.perf_counter()
    lopts = opt.lines.search()
    pairs = find_line_pairs(d.pts1, d.pts2, size1, size2, lopts)
    t1 = time.perf_counter()
    est.timings_ms["lines"] = 1e3 * (t1 - t0)
    scales = (working_scale(size1, lopts.width), working_scale(size2, lopts.width))
    fits: list[LineHomographyFit | None] = []  # per stage-2 arm; None: the unfixed arm
    stage1_s = [0.0]

    def stage2_arms() -> Iterator[FundamentalProblem]:
        """Stage 1 on the next line pair, run only when its stage-2 arm joins the race; with
        ``periodic_check``, arms of periodic line pairs are held back until the others joined
        and their matches are left out of the pools built from then on."""
        held: list[tuple[LineHomographyFit, FundamentalProblem]] = []
        for pair in pairs:
            if len(fits) >= opt.lines.max_line_pairs:
                return
            t = time.perf_counter()
            got = _stage2_arm(problem, opt, pair, size1, size2, scales, est)
            periodic = (
                got is not None
                and opt.lines.periodic_check
                and _periodic(got[0], d.pts1, scales[0])
            )
            stage1_s[0] += time.perf_counter() - t
            if got is None:
                continue
            if periodic:
                est.periodic_line_pairs += 1
                held.append(got)
                if problem.ambiguous is None:
                    problem.ambiguous = np.zeros(len(d), dtype=bool)
                problem.ambiguous[pair.support] = True
            else:
                fits.append(got[0])
                yield got[1]
        for fit, arm in held:
            if len(fits) >= opt.lines.max_line_pairs:
                return
            fits.append(fit)
            yield arm
        race = opt.race
        if race.unfixed_share > 0 and fits and len(fits) < opt.lines.max_line_pairs:
            fits.append(None)
            yield problem.whole(race_share=race.unfixed_share)

    result = run_ransac(
        stage2_arms(), problem.rng, problem.confidence, problem.budget.limit,
        race=RaceOptions(pool_rule=opt.race.race_pool, pool_ratio=opt.race.race_pool_ratio),
        budget=problem.budget,
        sampling=problem.sampling.loop(),
        min_samples=problem.min_samples(problem.model_points - 3), cls=CompiledLoop,
    )  # fmt: skip
    est.stage2_hypotheses += result.hypotheses
    if fits and result.leader >= 0 and fits[result.leader] is None:
        est.unfixed_lead = True
    elif fits and result.leader >= 0:
        best = fits[result.leader]
        assert best is not None  # the unfixed arm's case is above
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


def _escape(
    problem: FundamentalTask, line_search_cost: float, est: Estimate
) -> RansacResult | None:
    """The paper's escape (``separable.escape``): the first PROBE_SAMPLES samples of the
    standard loop, drawn from a copy of the task's generator without local optimisation, show
    the inlier ratio. When even PROBE_LO_GAIN times it leaves the line search paying for itself,
    the probe ends there; otherwise its best model is optimised locally once and its inlier
    ratio decides. When the line search cannot pay, that loop goes on to its end and its result
    is returned (``est.line_search_skipped``). Otherwise None: the task's generator is
    untouched, the probe's models count in ``est`` (stage 2's) and its time as
    ``timings_ms["probe"]``."""
    t = time.perf_counter()
    rng = copy_generator(problem.rng)
    loop = problem.standard_loop(rng)
    converged = loop.start(PROBE_SAMPLES)
    n = max(len(problem.data), 1)
    k, p = problem.model_points, problem.confidence
    keep = not converged and line_search_pays(
        min(1.0, PROBE_LO_GAIN * loop.best.count / n), k, p, line_search_cost
    )
    if not keep:
        loop.resume()  # the probe's best model, optimised locally: its inlier ratio decides
        keep = not loop.converged() and line_search_pays(
            loop.best.count / n, k, p, line_search_cost
        )
    if keep:
        est.stage2_hypotheses += loop.hypotheses
        est.timings_ms["probe"] = 1e3 * (time.perf_counter() - t)
        return None
    problem.rng = rng  # what follows (the final model's steps) draws on from the loop's stream
    result = loop.run()
    est.line_search_skipped = True
    est.stage2_hypotheses += result.hypotheses
    est.timings_ms["stage2"] = 1e3 * (time.perf_counter() - t)
    return result


def _stage2_arm(
    problem: FundamentalTask,
    opt: SeparableOptions,
    pair: LinePair,
    size1: tuple[float, float],
    size2: tuple[float, float],
    scales: tuple[float, float],
    est: Estimate,
) -> tuple[LineHomographyFit, FundamentalProblem] | None:
    """Stage 1 on ``pair``: (its fit, its stage-2 arm), or None when stage 1 fails or too few
    matches lie off the pair to sample from."""
    d = problem.data
    left = problem.budget.left()
    if left < 2:
        return None
    fit, h = fit_line_homography(
        pair, d.pts1, d.pts2, size1, size2, scales[0], scales[1], problem.rng,
        threshold=opt.lines.line_threshold, confidence=problem.confidence,
        min_inliers=opt.lines.min_line_inliers, max_samples=min(STAGE1_MAX_SAMPLES, left // 2),
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
    fixed = opt.fixed
    f1, f2 = _triples(fit, d.pts1, d.pts2, fixed.triple)
    tol = SAMPLE_PLANE_FACTOR * problem.threshold if fixed.sample_plane_check else 0.0
    fixed_tol = 0.0
    if fixed.triple != "all" and not problem.lmeds:
        fixed_tol = fixed.fixed_point_check * problem.threshold
    return fit, Stage2Problem(
        d,
        problem.solver,
        problem.threshold,
        problem.scoring,
        f1,
        f2,
        pool,
        scale=problem.scale,
        lo=problem.local.lo,
        plane_tol=tol,
        lo_data=problem.lo_data,
        fixed_tol=fixed_tol,
        oriented=problem.checks.oriented,
    )


def _periodic(fit: LineHomographyFit, pts1: np.ndarray, scale1: float) -> bool:
    """Whether the H_e inliers of ``fit`` on line 1 are a periodic point set: most of them on
    one projective arithmetic progression (``periodic.is_periodic`` in working px, tolerance
    PERIODIC_TOLERANCE). pts1: (N, 2) all matches in image 1, px; scale1: working px per px of
    image 1."""
    c = fit.ctrl1
    length = float(np.hypot(*(c[1] - c[0]))) * scale1
    return is_periodic(line_parameter(pts1[fit.inliers], c), length, PERIODIC_TOLERANCE)
