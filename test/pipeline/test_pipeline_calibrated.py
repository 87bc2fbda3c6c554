"""Calibrated estimation in the pipeline: matched points undistorted before estimation."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from sepfm_ros.geometry import symmetric_epipolar_distance
from sepfm_ros.geometry.calibrated.camera import camera_model, distort_points
from sepfm_ros.geometry.synthetic import make_pair
from sepfm_ros.pipeline.features import Matches
from sepfm_ros.pipeline.pipeline import MatchedPair, Pipeline, PipelineConfig

W, H = 1241, 376


@pytest.fixture(scope="module")
def kitti(shared_data):
    cams = json.loads((shared_data / "cameras.json").read_text())
    P_l = np.array(cams["kitti_seq2/left/000000.png"])
    P_r = np.array(cams["kitti_seq2/right/000000.png"])
    left = cv2.imread(str(shared_data / "kitti_seq2/left/000000.png"), cv2.IMREAD_GRAYSCALE)
    right = cv2.imread(str(shared_data / "kitti_seq2/right/000000.png"), cv2.IMREAD_GRAYSCALE)
    return P_l, P_r, left, right


def test_without_distortion_identical(kitti):
    P_l, P_r, left, right = kitti
    ma = camera_model(P_l[:, :3], [], "", np.eye(3), P_l, W, H)
    mb = camera_model(P_r[:, :3], [0.0] * 5, "plumb_bob", np.eye(3), P_r, W, H)
    pipe = Pipeline(PipelineConfig())
    plain = pipe.process(left, right)
    calibrated = pipe.process(left, right, cameras=(ma, mb))
    assert plain.coordinates == "image" and plain.image_matches is None
    assert calibrated.coordinates == "undistorted"
    np.testing.assert_array_equal(calibrated.estimate.F, plain.estimate.F)
    np.testing.assert_array_equal(calibrated.image_matches.pts_a, plain.matches.pts_a)
    assert "undistort" in calibrated.timings_ms and "undistort" not in plain.timings_ms


def test_distorted_points_estimated_in_undistorted_pixels():
    """A wide-angle lens: undistorting the matches lets one F explain them again."""
    pair = make_pair(n_inliers=400, n_outliers=100, noise=0.3, seed=3)
    w, h = pair.image_size
    K = np.array([[0.9 * w, 0, w / 2], [0, 0.9 * w, h / 2], [0, 0, 1.0]])
    lens = camera_model(K, [-0.3, 0.1, 0.0, 0.0, -0.02], "plumb_bob", np.eye(3), K_P(K), w, h)
    raw_a, raw_b = distort_points(lens, pair.pts1), distort_points(lens, pair.pts2)
    assert np.max(np.linalg.norm(raw_a - pair.pts1, axis=1)) > 10
    matched = MatchedPair(
        Matches(raw_a, raw_b, np.linspace(0.1, 0.8, len(raw_a))),
        (w, h),
        (w, h),
        {},
        PipelineConfig(),
        0.0,
    )
    pipe = Pipeline(PipelineConfig())
    plain = pipe.estimate(matched)
    calibrated = pipe.estimate(matched, cameras=(lens, lens))
    assert calibrated.ok and calibrated.coordinates == "undistorted"
    np.testing.assert_allclose(calibrated.matches.pts_a, pair.pts1, atol=1e-4)
    true = pair.is_inlier
    # in undistorted pixels the GT F holds; the estimate finds (nearly) all true matches
    found_cal = np.mean(calibrated.estimate.inliers[true])
    found_plain = np.mean(plain.estimate.inliers[true]) if plain.ok else 0.0
    assert found_cal > 0.9, found_cal
    assert found_plain < found_cal - 0.1, (found_plain, found_cal)
    d = symmetric_epipolar_distance(calibrated.estimate.F, pair.pts1[true], pair.pts2[true])
    assert np.median(d) < 0.5


def K_P(K: np.ndarray) -> np.ndarray:
    return np.concatenate([K, np.zeros((3, 1))], axis=1)
