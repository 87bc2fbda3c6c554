"""Run every selected method x seed over the pairs and keep per-run results.

One run = one method, one seed, one pair, on the pair's cached matches. Nothing here stops at a
bad pair or a method that raises: the pair becomes a :class:`PairError`, the run a failure with
its status, and the evaluation goes on.
"""

from __future__ import annotations

import math
import signal
import threading
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from sepfm_ros.evaluation import metrics
from sepfm_ros.evaluation.manifest import PairDataError, PairError, PairSpec
from sepfm_ros.evaluation.matches_cache import MatchesCache, PairMatches
from sepfm_ros.evaluation.methods import Method, MethodResult
from sepfm_ros.geometry.separable.stage1 import line_homography_error

#: Fewer putative matches than this and no compared method can run (eight-point methods).
MIN_MATCHES = 8


@dataclass(frozen=True)
class EvalConfig:
    """Settings shared by all methods: inlier threshold (px, symmetric epipolar distance),
    RANSAC confidence, the seeds each method runs with, and the baseline of paired comparisons."""

    threshold: float = 1.0
    confidence: float = 0.99
    seeds: tuple[int, ...] = (0, 1, 2)
    baseline: str = "ransac8"


@dataclass
class Example:
    """What the report draws for one pair: its matches, GT positives and one method's run."""

    pair: PairSpec
    pts_a: np.ndarray
    pts_b: np.ndarray
    positive: np.ndarray
    method: str
    result: MethodResult


@dataclass
class EvalResults:
    """Everything the report needs.

    Attributes:
        runs: one dict per run: pair, scene, method, seed, the RunMetrics fields, has_model,
            hypotheses / stage1_hypotheses / stage2_hypotheses (None when n/a), ms, own_inliers,
            status, fallback, line_search_skipped, line_inliers (count, separable methods).
        pairs: one dict per evaluated pair: pair, scene, kind, baseline, n_matches, n_positives,
            outlier_rate, cached.
        errors: pairs that could not be evaluated, with the reason.
        line_inliers: (method, count) per separable run that found a line pair.
        line_errors_est / line_errors_gt: scene -> line homography errors (px) of the line
            inliers under the stage-1 H_e and under the GT F, first separable method, all seeds.
        examples: scene -> Example (first evaluated pair of the scene, first seed).
        interrupted: the run was stopped (Ctrl-C); only whole pairs are kept.
    """

    config: EvalConfig
    methods: list[str]
    runs: list[dict] = field(default_factory=list)
    pairs: list[dict] = field(default_factory=list)
    errors: list[PairError] = field(default_factory=list)
    line_inliers: list[tuple[str, int]] = field(default_factory=list)
    line_errors_est: dict[str, list[float]] = field(default_factory=dict)
    line_errors_gt: dict[str, list[float]] = field(default_factory=dict)
    examples: dict[str, Example] = field(default_factory=dict)
    interrupted: bool = False


def _safe_run(method: Method, pts_a, pts_b, size_a, size_b, cfg: EvalConfig, seed: int):
    try:
        return method.run(pts_a, pts_b, size_a, size_b, cfg.threshold, cfg.confidence, seed)
    except Exception as exc:  # a method that raises is a failed run, not a crashed evaluation
        hyp = None if method.family == "opencv" else 0
        return MethodResult(None, 0, hyp, hyp, hyp, math.nan, status=f"error: {exc!r}")


def _pair_matches(res: EvalResults, pair: PairSpec, cache: MatchesCache) -> PairMatches | None:
    """The pair's putative matches (at least :data:`MIN_MATCHES`), or None after recording in
    ``res.errors`` why the pair cannot be evaluated."""
    try:
        pm = cache.matches(pair)
        n = pm.pts_a.shape[0]
        if n < MIN_MATCHES:
            raise PairDataError(
                f"fewer than {MIN_MATCHES} matches ({n} with {cache.settings.features}, "
                f"ratio {cache.settings.ratio}): nothing to estimate from"
            )
    except PairDataError as exc:
        res.errors.append(PairError(pair.pair_id, pair.scene, str(exc)))
        return None
    except Exception as exc:  # e.g. cv2.error on a corrupt image
        res.errors.append(PairError(pair.pair_id, pair.scene, f"matching failed: {exc!r}"))
        return None
    return pm


def _pair_row(pair: PairSpec, pm: PairMatches, positive: np.ndarray) -> dict:
    """The pair's row of ``EvalResults.pairs``; ``positive``: (N,) bool, the GT positives."""
    n = pm.pts_a.shape[0]
    n_pos = int(np.count_nonzero(positive))
    return {
        "pair": pair.pair_id,
        "scene": pair.scene,
        "kind": pair.kind,
        "baseline": pair.baseline,
        "n_matches": n,
        "n_positives": n_pos,
        "outlier_rate": metrics.outlier_rate(n_pos, n),
        "cached": pm.from_cache,
    }


def _gt_cameras(
    pair: PairSpec, cameras: Mapping[Path, np.ndarray] | None
) -> tuple[np.ndarray, np.ndarray] | None:
    """The GT 3x4 cameras of the pair's two images, or None unless both have one."""
    if cameras and pair.img_a is not None and pair.img_b is not None:
        P_a, P_b = cameras.get(pair.img_a.resolve()), cameras.get(pair.img_b.resolve())
        return (P_a, P_b) if P_a is not None and P_b is not None else None
    return None


def _run_row(
    pair: PairSpec,
    pm: PairMatches,
    positive: np.ndarray,
    gt_cams: tuple[np.ndarray, np.ndarray] | None,
    method: Method,
    seed: int,
    r: MethodResult,
    cfg: EvalConfig,
) -> dict:
    """One run's row of ``EvalResults.runs`` (see there for the columns, in this order);
    the pose errors (deg) are None without ``gt_cams``."""
    m = metrics.run_metrics(r.F, pm.pts_a, pm.pts_b, positive, cfg.threshold)
    rec = {"pair": pair.pair_id, "scene": pair.scene, "method": method.name}
    rec["seed"] = seed
    rec.update(asdict(m))
    rot_err = dir_err = None
    if gt_cams is not None:
        rot_err, dir_err = metrics.pose_errors(r.F, pm.pts_a, pm.pts_b, *gt_cams, cfg.threshold)
    rec.update(rotation_error_deg=rot_err, translation_error_deg=dir_err)
    rec.update(
        has_model=r.F is not None,
        hypotheses=r.hypotheses,
        stage1_hypotheses=r.stage1_hypotheses,
        stage2_hypotheses=r.stage2_hypotheses,
        ms=r.ms,
        own_inliers=r.own_inliers,
        status=r.status,
        fallback=r.fallback,
        line_search_skipped=r.line_search_skipped,
        line_inliers=len(r.line_inliers) if method.separable else None,
    )
    return rec


def _keep_run_extras(
    res: EvalResults,
    pair: PairSpec,
    pm: PairMatches,
    positive: np.ndarray,
    methods: Sequence[Method],
    method: Method,
    seed: int,
    r: MethodResult,
) -> None:
    """What the report draws besides the run's row: the line inliers (and, for the first
    separable method, the line homography errors) of a run that found a line pair, and the
    scene's example (first seed of the first separable method, else of the first method)."""
    line_method = next((m.name for m in methods if m.separable), None)
    if method.separable and r.line_pair is not None and len(r.line_inliers):
        res.line_inliers.append((method.name, len(r.line_inliers)))
        if method.name == line_method:
            _collect_line_errors(res, r, pm.pts_a, pm.pts_b, pair)
    if pair.scene not in res.examples and seed == res.config.seeds[0]:
        if method.name == (line_method or methods[0].name):
            res.examples[pair.scene] = Example(pair, pm.pts_a, pm.pts_b, positive, method.name, r)


def _evaluate_pair(
    res: EvalResults,
    pair: PairSpec,
    methods: Sequence[Method],
    cache: MatchesCache,
    progress: Callable[[int, str], None] | None,
    cameras: Mapping[Path, np.ndarray] | None = None,
) -> None:
    """Match one pair and run every method x seed on it, appending to ``res``."""
    cfg = res.config
    pm = _pair_matches(res, pair, cache)
    if pm is None:
        if progress:
            progress(len(methods) * len(cfg.seeds), pair.pair_id)
        return
    size_b = pm.size_b or pm.size_a
    positive = metrics.positives(pair.F_gt, pm.pts_a, pm.pts_b)
    res.pairs.append(_pair_row(pair, pm, positive))
    gt_cams = _gt_cameras(pair, cameras)
    for method in methods:
        for seed in cfg.seeds:
            r = _safe_run(method, pm.pts_a, pm.pts_b, pm.size_a, size_b, cfg, seed)
            res.runs.append(_run_row(pair, pm, positive, gt_cams, method, seed, r, cfg))
            _keep_run_extras(res, pair, pm, positive, methods, method, seed, r)
            if progress:
                progress(1, pair.pair_id)


def evaluate(
    pairs: Sequence[PairSpec],
    methods: Sequence[Method],
    cache: MatchesCache,
    config: EvalConfig | None = None,
    errors: Sequence[PairError] = (),
    progress: Callable[[int, str], None] | None = None,
    cameras: Mapping[Path, np.ndarray] | None = None,
) -> EvalResults:
    """Evaluate ``methods`` on ``pairs``.

    Args:
        pairs: valid pairs (from :func:`~sepfm_ros.evaluation.manifest.load_manifest`).
        methods: from :func:`~sepfm_ros.evaluation.methods.resolve_methods`.
        cache: where matches come from.
        config: threshold, confidence, seeds, baseline.
        errors: pair errors found while loading, carried into the results.
        progress: called with (steps done since last call, current pair id); one step per run,
            len(pairs) * len(methods) * len(seeds) in all.
        cameras: GT 3x4 cameras by resolved image path (``manifest.load_cameras``); pairs
            whose two images have one get the relative-pose errors of every run
            (``rotation_error_deg``, ``translation_error_deg``; None otherwise).
    """
    cfg = config or EvalConfig()
    res = EvalResults(config=cfg, methods=[m.name for m in methods], errors=list(errors))
    # Ctrl-C sets a flag checked between pairs: a KeyboardInterrupt raised while numba compiles
    # a kernel is lost, so the default handler alone could let the run go on to the end
    stop = threading.Event()
    previous = None
    if threading.current_thread() is threading.main_thread():
        previous = signal.signal(signal.SIGINT, lambda signum, frame: stop.set())
    try:
        for pair in pairs:
            if stop.is_set():
                raise KeyboardInterrupt
            _evaluate_pair(res, pair, methods, cache, progress, cameras)
    except KeyboardInterrupt:
        # keep whole pairs only: drop the runs of the pair that was interrupted
        res.interrupted = True
        complete = len(methods) * len(cfg.seeds)
        if res.pairs and sum(r["pair"] == res.pairs[-1]["pair"] for r in res.runs) < complete:
            last = res.pairs.pop()["pair"]
            res.runs = [r for r in res.runs if r["pair"] != last]
            res.examples = {k: v for k, v in res.examples.items() if v.pair.pair_id != last}
    finally:
        if previous is not None:
            signal.signal(signal.SIGINT, previous)
    return res


def _collect_line_errors(res: EvalResults, r: MethodResult, pts_a, pts_b, pair: PairSpec) -> None:
    idx = r.line_inliers
    la, lb = (np.asarray(line, dtype=np.float64) for line in r.line_pair)
    if r.H_e is not None and r.control_points is not None:
        # the estimator's own stage-1 H_e, as in the paper's Fig. 8
        e = line_homography_error(r.H_e, r.control_points, pts_a[idx], pts_b[idx])
        res.line_errors_est.setdefault(pair.scene, []).extend(float(x) for x in e)
    e = metrics.line_homography_error(pair.F_gt, la, lb, pts_a[idx], pts_b[idx])
    res.line_errors_gt.setdefault(pair.scene, []).extend(float(x) for x in e)


def per_pair_values(runs: list[dict], method: str, key: str) -> dict[str, float]:
    """pair id -> the seed-average of ``key`` for ``method`` (NaN when every seed is NaN)."""
    acc: dict[str, list[float]] = {}
    for r in runs:
        if r["method"] == method:
            v = r[key]
            acc.setdefault(r["pair"], []).append(math.nan if v is None else float(v))
    out = {}
    for k, vals in acc.items():
        finite = [v for v in vals if not math.isnan(v)]
        out[k] = float(np.mean(finite)) if finite else math.nan
    return out
