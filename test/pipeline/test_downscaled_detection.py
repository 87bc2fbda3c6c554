"""Features of wide images found on a downscaled copy, matches in full-resolution pixels
(``PipelineConfig.feature_max_width``)."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from ground_truth import median_gt_inlier_error

from sepfm_ros.geometry import estimate_fundamental
from sepfm_ros.pipeline.config import FEATURE_MAX_WIDTH
from sepfm_ros.pipeline.features import (
    detect,
    detection_factor,
    downscaled,
    make_detector,
    to_full_resolution,
)
from sepfm_ros.pipeline.pipeline import Pipeline, PipelineConfig


def test_detection_factor_is_the_smallest_integer_that_fits():
    assert detection_factor(1920, 1280) == 2
    assert detection_factor(3840, 1280) == 3
    assert detection_factor(1536, 1280) == 2
    assert detection_factor(1281, 1280) == 2
    # VGA, KITTI, 720p, Strecha's photographs: full size at the default; 1080p by half
    for width in (640, 1241, 1242, 1280, 1536):
        assert detection_factor(width, FEATURE_MAX_WIDTH) == 1
    assert detection_factor(1920, FEATURE_MAX_WIDTH) == 2
    assert detection_factor(1920, 0) == 1  # 0: never


@pytest.mark.parametrize(
    ("width", "height", "factor"),
    [(1920, 1080, 2), (1536, 1024, 2), (1235, 371, 2), (1537, 1023, 3)],
)
def test_downscaled_pixel_centres_map_back_exactly(width, height, factor):
    """On images whose value is the pixel's own x (or y), INTER_AREA's box average at a small
    pixel is the full-resolution coordinate of that pixel's centre: to_full_resolution must give
    it, for a factor that divides the size and for one that does not (per-axis scale)."""
    xs = np.tile(np.arange(width, dtype=np.float32), (height, 1))
    ys = np.tile(np.arange(height, dtype=np.float32)[:, None], (1, width))
    small_x, scale = downscaled(xs, factor)
    small_y, _ = downscaled(ys, factor)
    h, w = small_x.shape
    assert (w, h) == (-(-width // factor), -(-height // factor))
    u, v = np.meshgrid(np.arange(w), np.arange(h))
    full = to_full_resolution(np.stack([u.ravel(), v.ravel()], axis=1), scale)
    np.testing.assert_allclose(full[:, 0], small_x.ravel(), atol=2e-3)
    np.testing.assert_allclose(full[:, 1], small_y.ravel(), atol=2e-3)
    # the naive x_small * s is off by (s - 1) / 2 px
    assert np.abs(u.ravel() * scale[0] - small_x.ravel()).max() > 0.4


def kitti_frame(shared_data) -> np.ndarray:
    img = cv2.imread(str(shared_data / "kitti_seq2/left/000000.png"), cv2.IMREAD_GRAYSCALE)
    assert img is not None
    return img


def test_detect_returns_the_downscaled_keypoints_in_full_resolution_pixels(shared_data):
    img = kitti_frame(shared_data)[:, :1235]  # 1235 px: factor 2, scale 1235 / 618
    detector = make_detector("orb", 500)
    pts, desc = detect(img, detector, max_width=640)
    small, scale = downscaled(img, 2)
    pts_small, desc_small = detect(small, detector)
    np.testing.assert_array_equal(desc, desc_small)
    np.testing.assert_allclose(pts, (pts_small + 0.5) * np.array(scale) - 0.5)
    assert pts[:, 0].max() > 640  # spread over the full-size image


def test_pipeline_matches_of_a_shifted_frame_are_in_full_resolution_pixels(shared_data):
    """Image b is image a moved by (-6, -5) px: detected downscaled by 2, the matches still
    show the full-size shift."""
    img = kitti_frame(shared_data)
    a, b = img[:-5, :-6], img[5:, 6:]  # a point (x, y) of a is (x - 6, y - 5) in b
    pipeline = Pipeline(PipelineConfig(feature_max_width=640))
    matched = pipeline.match(a, b)
    assert matched.detection_factors == (2, 2)
    assert matched.size_a == (1235, 371)
    shift = np.median(matched.matches.pts_b - matched.matches.pts_a, axis=0)
    np.testing.assert_allclose(shift, [-6.0, -5.0], atol=0.25)
    assert len(matched.matches) >= 100


@pytest.mark.parametrize(
    ("name_a", "name_b"),
    [
        ("kitti_seq2/left/000000.png", "kitti_seq2/left/000001.png"),
        ("templeRing/templeR0001.png", "templeRing/templeR0002.png"),
    ],
)
def test_kitti_and_vga_are_detected_at_full_size_by_default(shared_data, name_a, name_b):
    a = cv2.imread(str(shared_data / name_a), cv2.IMREAD_GRAYSCALE)
    b = cv2.imread(str(shared_data / name_b), cv2.IMREAD_GRAYSCALE)
    default = Pipeline(PipelineConfig()).match(a, b)
    full = Pipeline(PipelineConfig(feature_max_width=0)).match(a, b)
    assert default.detection_factors == (1, 1)
    np.testing.assert_array_equal(default.matches.pts_a, full.matches.pts_a)
    np.testing.assert_array_equal(default.matches.pts_b, full.matches.pts_b)


def test_a_changed_max_width_drops_cached_features(shared_data):
    img = kitti_frame(shared_data)
    pipeline = Pipeline(PipelineConfig(), cache_size=4)
    pipeline.match(img, img[:, ::-1].copy(), key_a=1, key_b=2)
    pipeline.update(feature_max_width=640)
    matched = pipeline.match(img, img[:, ::-1].copy(), key_a=1, key_b=2)
    assert pipeline.images_cached == 0 and pipeline.images_detected == 4
    assert matched.detection_factors == (2, 2)


def test_negative_max_width_is_rejected():
    with pytest.raises(ValueError, match="feature_max_width"):
        PipelineConfig(feature_max_width=-1)


def test_high_resolution_pair_downscaled_recovers_the_gt_F(shared_data_lines):
    """A 1536x1024 Strecha pair at the default (detected at 768x512): F in full-size pixels
    agrees with the ground truth within 1 px on the GT inliers."""
    pairs = json.loads((shared_data_lines / "pairs.json").read_text())
    pair = next(p for p in pairs if p["img_a"] == "fountain-P11/0000.jpg")
    a, b = (
        cv2.cvtColor(cv2.imread(str(shared_data_lines / pair[k])), cv2.COLOR_BGR2GRAY)
        for k in ("img_a", "img_b")
    )
    result = Pipeline(PipelineConfig()).process(a, b)
    assert result.size_a == (1536, 1024)
    est = estimate_fundamental(result.matches.pts_a, result.matches.pts_b, (1536, 1024), seed=0)
    assert est.F is not None
    F_gt = np.asarray(pair["F"], dtype=np.float64)
    err, n = median_gt_inlier_error(est.F, F_gt, result.matches.pts_a, result.matches.pts_b)
    assert n >= 20 and err < 1.0, (err, n)
