"""What decides a pipeline result: :class:`PipelineConfig` and its checks. No ROS.

A light module (no estimator, no compiled kernels), so that parameter tables and ``--help`` can
use the configuration without loading the pipeline.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from sepfm_ros.geometry.options import DEFAULT_METHOD, METHODS, EstimatorOptions
from sepfm_ros.pipeline.detectors import FEATURES, unavailable_reason

# The fewest matches any estimator method accepts (eight-point needs 8).
MIN_MATCHES = 8
# Images wider than this are detected downscaled (PipelineConfig.feature_max_width): above KITTI's
# 1242 px, 720p's 1280 and the 1536 px photographs of ../shared/data_lines, so these are detected
# at full size, and 1080p (1920 px) by half.
FEATURE_MAX_WIDTH = 1600


@dataclass(frozen=True)
class PipelineConfig:
    """Everything that decides a pipeline result.

    Attributes:
        features: detector/descriptor, one of ``FEATURES`` ("orb", "sift", "akaze").
        max_features: keypoints per image (ORB/SIFT), >= 8.
        feature_max_width: an image wider than this (px) is detected on a copy downscaled by
            the integer factor s = ceil(width / feature_max_width) (``cv2.INTER_AREA``); its
            keypoints are mapped back to full-resolution pixels, x = (x_small + 0.5) s - 0.5,
            so matches, F and errors are in the image's own pixels. 0 = always full size.
        ratio: Lowe ratio-test bound in (0, 1].
        method: estimator method, one of ``sepfm_ros.geometry.METHODS``.
        threshold_px: inlier threshold, symmetric epipolar distance in pixels, > 0.
        confidence: RANSAC confidence in (0, 1).
        seed: seed of every random choice of the estimator; the same for every pair, so a pair
            of images gives the same F live and offline.
        max_matches: keep at most this many best matches for the estimator (0 = all).
        estimator_options: the estimator's options (``EstimatorOptions``; default: its defaults).
    """

    features: str = "orb"
    max_features: int = 1000
    feature_max_width: int = FEATURE_MAX_WIDTH
    ratio: float = 0.8
    method: str = DEFAULT_METHOD
    threshold_px: float = 1.0
    confidence: float = 0.99
    seed: int = 0
    max_matches: int = 0
    estimator_options: EstimatorOptions = field(default_factory=EstimatorOptions)

    def __post_init__(self) -> None:
        errors = config_errors(self)
        if errors:
            raise ValueError("invalid pipeline config: " + "; ".join(errors))


def config_errors(config: PipelineConfig) -> list[str]:
    """Human-readable reasons why ``config`` is invalid (empty when valid)."""
    errors = []
    if config.features not in FEATURES:
        errors.append(f"features must be one of {FEATURES}, got {config.features!r}")
    elif (reason := unavailable_reason(config.features)) is not None:
        errors.append(reason)
    if config.method not in METHODS:
        errors.append(f"method must be one of {METHODS}, got {config.method!r}")
    if not int(config.max_features) >= MIN_MATCHES:
        errors.append(f"max_features must be >= {MIN_MATCHES}, got {config.max_features}")
    if int(config.feature_max_width) < 0:
        errors.append(f"feature_max_width must be >= 0, got {config.feature_max_width}")
    if not 0.0 < float(config.ratio) <= 1.0:
        errors.append(f"ratio must be in (0, 1], got {config.ratio}")
    if not float(config.threshold_px) > 0.0:
        errors.append(f"threshold_px must be > 0, got {config.threshold_px}")
    if not 0.0 < float(config.confidence) < 1.0:
        errors.append(f"confidence must be in (0, 1), got {config.confidence}")
    if int(config.seed) < 0:
        errors.append(f"seed must be >= 0, got {config.seed}")
    if int(config.max_matches) < 0:
        errors.append(f"max_matches must be >= 0, got {config.max_matches}")
    return errors
