"""Images -> matches -> fundamental-matrix estimate, with per-stage timings. No ROS.

One :class:`Pipeline` serves the live node and offline bag processing, so the same images with
the same :class:`PipelineConfig` (including ``seed``) give the same result in both::

    pipeline = Pipeline(PipelineConfig(features="orb", max_features=1000, seed=0))
    result = pipeline.process(image_a, image_b)       # numpy images (H, W) or (H, W, 3)
    result.estimate.F, result.matches, result.errors, result.timings_ms

Callers that decode the images themselves (e.g. from ROS messages) pass the time it took as
``prior_timings_ms={"decode": ms}``; it is reported first and counted in the total. Detected
features can be cached by a caller-chosen key (e.g. a frame's stamp), so in motion mode each
frame is detected once.

``process`` is ``estimate(match(...))``: :meth:`Pipeline.match` (features and matches, C code that
releases the GIL) and :meth:`Pipeline.estimate` (the estimator, mostly Python) may run on two
threads, one pair apart, as the live node does; the result of a pair does not change.

Timing stages (milliseconds): ``decode`` (when given), ``features``, ``match``, ``estimate`` (the
whole estimator call), the estimator's own stages when it reports them (``lines`` = line-pair
search, ``stage1``, ``stage2``, ``refine``), ``subpixel`` (with ``subpixel_b``) and ``total``.

With ``subpixel_b`` (a calibrated stereo rig's stream), :meth:`Pipeline.match` also tracks each
match's point of image a into image b to sub-pixel accuracy
(:func:`~sepfm_ros.pipeline.subpixel.refine_points_b`): ``PipelineResult.refined_b``, for the
calibration's correction; F and everything else stay those of the matches as detected.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Hashable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from typing import Any

import cv2
import numpy as np

from sepfm_ros.geometry import (
    Estimate,
    StatusCode,
    estimate_fundamental,
    symmetric_epipolar_distance,
)
from sepfm_ros.geometry.calibrated.camera import CameraModel, undistort_points
from sepfm_ros.pipeline.config import MIN_MATCHES, PipelineConfig
from sepfm_ros.pipeline.features import (
    Matches,
    detect,
    detection_factor,
    make_detector,
    match_descriptors,
)
from sepfm_ros.pipeline.subpixel import refine_points_b

ESTIMATOR_STAGES = ("lines", "stage1", "stage2", "refine")


@dataclass
class MatchedPair:
    """The first half of a pipeline result (see :meth:`Pipeline.match`).

    Attributes:
        matches: putative matches without duplicates, best first.
        size_a, size_b: (width, height) of the two images.
        timings_ms: stages so far (prior stages, "features", "match").
        config: the config the matches were made with (the estimate uses it too).
        busy_ms: milliseconds spent so far (prior stages included), counted in "total".
        refined_b: with ``subpixel_b``, (N, 2) sub-pixel points in image b of ``matches.pts_a``
            (image pixels, NaN where tracking failed); else None.
    """

    matches: Matches
    size_a: tuple[int, int]
    size_b: tuple[int, int]
    timings_ms: dict[str, float]
    config: PipelineConfig
    busy_ms: float
    refined_b: np.ndarray | None = None

    @property
    def detection_factors(self) -> tuple[int, int]:
        """The factor each image was downscaled by for detection (1: full size;
        ``PipelineConfig.feature_max_width``); the matches are in full-size pixels."""
        max_width = self.config.feature_max_width
        return detection_factor(self.size_a[0], max_width), detection_factor(
            self.size_b[0], max_width
        )


@dataclass
class PipelineResult:
    """What the pipeline made of one image pair.

    Attributes:
        matches: putative matches without duplicates, best first (pts_a in image a, pts_b in b).
        estimate: the estimator's result; ``estimate.F`` maps a to b (``x_b^T F x_a = 0``), or
            None with ``estimate.status`` saying why.
        errors: (N,) float64 symmetric epipolar distance (px) of every match under F; NaN when
            F is None.
        on_line: (N,) bool, matches on the estimator's line pair that agree with H_e.
        size_a, size_b: (width, height) of the two images.
        timings_ms: stage -> milliseconds (see the module docstring).
        coordinates: the pixels of ``matches``, ``errors`` and F: "image" (as detected) or
            "undistorted" (undistorted pixels of each camera's K, when cameras were given).
        image_matches: with cameras, the matches in image pixels as detected; else None.
        refined_b: with the pipeline's ``subpixel_b``, (N, 2) sub-pixel points in image b of
            ``matches.pts_a`` in the pixels of ``coordinates`` (NaN where tracking failed);
            else None.
    """

    matches: Matches
    estimate: Estimate
    errors: np.ndarray
    on_line: np.ndarray
    size_a: tuple[int, int]
    size_b: tuple[int, int]
    timings_ms: dict[str, float]
    coordinates: str = "image"
    image_matches: Matches | None = None
    refined_b: np.ndarray | None = None

    @property
    def ok(self) -> bool:
        """True when a usable F was estimated."""
        return self.estimate.ok


def _load_prctl() -> Callable[..., int] | None:
    try:
        return ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True).prctl
    except (OSError, AttributeError):
        return None


_PRCTL = _load_prctl()
_PR_SET_NAME = 15


def name_native_thread(name: str | None = None) -> None:
    """Give the calling thread its Python name in the OS too (``top -H``, ``/proc/.../comm``).

    Python 3.11 leaves every thread named after the process; with the name, the CPU of each of
    the node's threads can be read from ``/proc`` (benchmarks/bench_node.py does). Linux only,
    15 characters; elsewhere a no-op.
    """
    if _PRCTL is None:
        return
    text = (name or threading.current_thread().name).encode()[:15]
    try:
        _PRCTL(_PR_SET_NAME, ctypes.c_char_p(text), 0, 0, 0)
    except (OSError, ctypes.ArgumentError):
        pass


def _ms(t0: float) -> float:
    return (time.perf_counter() - t0) * 1e3


class Pipeline:
    """Two images in, matches and F out. Not thread-safe: one pipeline per worker thread.

    With ``parallel_detect`` a pair whose two images both need detection (stereo) has image b
    detected on a helper thread (own detector; OpenCV releases the GIL) while image a is
    detected on the caller's thread: the same features, in about half the time on two cores.
    """

    def __init__(
        self,
        config: PipelineConfig | None = None,
        cache_size: int = 4,
        parallel_detect: bool = False,
        subpixel_b: bool = False,
    ) -> None:
        """``subpixel_b``: also track each match into image b to sub-pixel accuracy (see the
        module docstring)."""
        self.subpixel_b = bool(subpixel_b)
        self._cache: OrderedDict[Hashable, tuple[np.ndarray, np.ndarray | None]] = OrderedDict()
        self._cache_size = int(cache_size)
        self.images_detected = 0  # images whose features were computed
        self.images_cached = 0  # images whose features came from the cache
        self._config = PipelineConfig()
        self._detector: cv2.Feature2D | None = None
        self._detector_b: cv2.Feature2D | None = None  # the helper's (parallel_detect)
        self._helper = (
            ThreadPoolExecutor(
                1,
                thread_name_prefix="sepfm-detect",
                initializer=name_native_thread,
                initargs=("sepfm-detect",),
            )
            if parallel_detect
            else None
        )
        self.configure(config or PipelineConfig())

    @property
    def config(self) -> PipelineConfig:
        return self._config

    def configure(self, config: PipelineConfig) -> None:
        """Switch to ``config``; drops cached features when the detector or the detection
        size changes."""
        old = self._config
        if self._detector is None or (config.features, config.max_features) != (
            old.features,
            old.max_features,
        ):
            self._detector = make_detector(config.features, config.max_features)
            if self._helper is not None:
                self._detector_b = make_detector(config.features, config.max_features)
            self._cache.clear()
        if config.feature_max_width != old.feature_max_width:
            self._cache.clear()
        self._config = config

    def update(self, **changes: Any) -> PipelineConfig:
        """Configure with some fields changed (validated); returns the new config."""
        config = replace(self._config, **changes)
        self.configure(config)
        return config

    def _cached(self, key: Hashable | None) -> tuple[np.ndarray, np.ndarray | None] | None:
        if key is not None and key in self._cache:
            self._cache.move_to_end(key)
            self.images_cached += 1
            return self._cache[key]
        return None

    def _store(
        self, key: Hashable | None, feats: tuple[np.ndarray, np.ndarray | None]
    ) -> tuple[np.ndarray, np.ndarray | None]:
        self.images_detected += 1
        if key is not None and self._cache_size > 0:
            self._cache[key] = feats
            while len(self._cache) > self._cache_size:
                self._cache.popitem(last=False)
        return feats

    def _features(
        self, image: np.ndarray, key: Hashable | None
    ) -> tuple[np.ndarray, np.ndarray | None]:
        cached = self._cached(key)
        assert self._detector is not None  # made by configure
        if cached is not None:
            return cached
        return self._store(key, detect(image, self._detector, self._config.feature_max_width))

    def _pair_features(
        self,
        image_a: np.ndarray,
        image_b: np.ndarray,
        key_a: Hashable | None,
        key_b: Hashable | None,
    ) -> tuple[tuple[np.ndarray, np.ndarray | None], tuple[np.ndarray, np.ndarray | None]]:
        """Features of both images: cached, or detected (b on the helper thread if any)."""
        cached = key_a in self._cache or key_b in self._cache
        if self._helper is None or cached or (key_a is not None and key_a == key_b):
            return self._features(image_a, key_a), self._features(image_b, key_b)
        assert self._detector is not None and self._detector_b is not None  # made by configure
        max_width = self._config.feature_max_width
        pending_b = self._helper.submit(detect, image_b, self._detector_b, max_width)
        feats_a = self._store(key_a, detect(image_a, self._detector, max_width))
        return feats_a, self._store(key_b, pending_b.result())

    def match(
        self,
        image_a: np.ndarray,
        image_b: np.ndarray,
        key_a: Hashable | None = None,
        key_b: Hashable | None = None,
        prior_timings_ms: dict[str, float] | None = None,
    ) -> MatchedPair:
        """First half of :meth:`process`: features (cached by key) and matches of a pair.

        Runs on the thread that owns this pipeline (it uses the feature cache); the result
        carries the config it was made with, so :meth:`estimate` may run on another thread.
        """
        t_start = time.perf_counter()
        cfg = self._config
        timings: dict[str, float] = dict(prior_timings_ms or {})
        size_a = (int(image_a.shape[1]), int(image_a.shape[0]))
        size_b = (int(image_b.shape[1]), int(image_b.shape[0]))

        t0 = time.perf_counter()
        (pts_a, desc_a), (pts_b, desc_b) = self._pair_features(image_a, image_b, key_a, key_b)
        timings["features"] = _ms(t0)

        t0 = time.perf_counter()
        matches = match_descriptors(pts_a, desc_a, pts_b, desc_b, cfg.features, cfg.ratio)
        if cfg.max_matches and len(matches) > cfg.max_matches:
            k = cfg.max_matches
            matches = Matches(matches.pts_a[:k], matches.pts_b[:k], matches.ratio[:k])
        timings["match"] = _ms(t0)
        refined_b = None
        if self.subpixel_b:
            t0 = time.perf_counter()
            try:
                refined_b = refine_points_b(image_a, image_b, matches.pts_a, matches.pts_b)
            except cv2.error:  # the correction then fits the detected points; F is unaffected
                refined_b = None
            timings["subpixel"] = _ms(t0)
        busy = _ms(t_start) + sum((prior_timings_ms or {}).values())
        return MatchedPair(matches, size_a, size_b, timings, cfg, busy, refined_b)

    def estimate(
        self, matched: MatchedPair, cameras: tuple[CameraModel, CameraModel] | None = None
    ) -> PipelineResult:
        """Second half of :meth:`process`: F from ``matched`` under ``matched.config``.

        Uses no pipeline state, so it may run on another thread than :meth:`match` (e.g. the
        live node estimates one pair while it matches the next).

        Args:
            cameras: optional (camera of image a, camera of image b). When given, the matched
                points are undistorted (:func:`undistort_points`,
                the identity for D = 0) before estimation, so F, ``matches`` and ``errors`` are
                in undistorted pixels of K (``result.coordinates == "undistorted"``); timed as
                stage "undistort".
        """
        t_start = time.perf_counter()
        matches = matched.matches
        timings = dict(matched.timings_ms)
        image_matches = None
        refined_b = matched.refined_b
        if cameras is not None:
            t0 = time.perf_counter()
            image_matches = matches
            matches = Matches(
                undistort_points(cameras[0], matches.pts_a),
                undistort_points(cameras[1], matches.pts_b),
                matches.ratio,
            )
            if refined_b is not None:
                refined_b = _undistort_finite(cameras[1], refined_b)
            timings["undistort"] = _ms(t0)
        t0 = time.perf_counter()
        estimate = _estimate(matches, matched.size_a, matched.size_b, matched.config)
        timings["estimate"] = _ms(t0)
        for stage in ESTIMATOR_STAGES:
            if stage in estimate.timings_ms:
                timings[stage] = float(estimate.timings_ms[stage])

        n = len(matches)
        if estimate.F is not None and n:
            errors = symmetric_epipolar_distance(estimate.F, matches.pts_a, matches.pts_b)
            errors = np.asarray(errors, dtype=np.float64).reshape(n)
        else:
            errors = np.full(n, np.nan)
        on_line = np.zeros(n, dtype=bool)
        if len(estimate.line_inliers):
            idx = np.asarray(estimate.line_inliers, dtype=np.int64)
            on_line[idx[(idx >= 0) & (idx < n)]] = True
        timings["total"] = matched.busy_ms + _ms(t_start)
        return PipelineResult(
            matches,
            estimate,
            errors,
            on_line,
            matched.size_a,
            matched.size_b,
            timings,
            "image" if cameras is None else "undistorted",
            image_matches,
            refined_b,
        )

    def process(
        self,
        image_a: np.ndarray,
        image_b: np.ndarray,
        key_a: Hashable | None = None,
        key_b: Hashable | None = None,
        prior_timings_ms: dict[str, float] | None = None,
        cameras: tuple[CameraModel, CameraModel] | None = None,
    ) -> PipelineResult:
        """Match ``image_a`` to ``image_b`` and estimate F (``x_b^T F x_a = 0``).

        The same as ``estimate(match(...))``.

        Args:
            image_a, image_b: (H, W) or (H, W, 3|4) numpy images (8-bit, or stretched to 8 bits).
            key_a, key_b: optional hashable keys under which detected features are cached
                (same key = same image); None disables caching for that image.
            prior_timings_ms: stages the caller ran before (e.g. {"decode": 3.2}), reported
                first in ``timings_ms`` and added to its "total".
            cameras: optional camera models of a and b: estimate in undistorted pixels of K
                (see :meth:`estimate`).
        Returns:
            A :class:`PipelineResult`. Estimation failures (too few matches, degenerate data)
            are reported in ``result.estimate.status`` with ``F`` None, never raised.
        """
        return self.estimate(self.match(image_a, image_b, key_a, key_b, prior_timings_ms), cameras)


def _undistort_finite(camera: CameraModel, pts: np.ndarray) -> np.ndarray:
    """(N, 2) undistorted pixels of K of the finite rows of ``pts`` (N, 2); NaN rows stay NaN."""
    out = np.full(pts.shape, np.nan)
    ok = np.all(np.isfinite(pts), axis=1)
    if np.any(ok):
        out[ok] = undistort_points(camera, pts[ok])
    return out


def _estimate(
    matches: Matches, size_a: tuple[int, int], size_b: tuple[int, int], cfg: PipelineConfig
) -> Estimate:
    n = len(matches)
    if n < MIN_MATCHES:
        return Estimate(
            F=None,
            inliers=np.zeros(n, dtype=bool),
            status=f"too few matches: {n} < {MIN_MATCHES}",
            code=StatusCode.TOO_FEW_MATCHES,
            method=cfg.method,
        )
    try:
        return estimate_fundamental(
            matches.pts_a,
            matches.pts_b,
            size_a,
            size_b,
            method=cfg.method,
            threshold=cfg.threshold_px,
            confidence=cfg.confidence,
            seed=cfg.seed,
            options=cfg.estimator_options,
        )
    except ValueError as err:  # the estimator's "bad input" contract
        return Estimate(
            F=None,
            inliers=np.zeros(n, dtype=bool),
            status=f"estimator rejected input: {err}",
            code=StatusCode.BAD_INPUT,
            method=cfg.method,
        )
