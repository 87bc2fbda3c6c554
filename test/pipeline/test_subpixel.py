"""Sub-pixel points of image b for the correction: tracked to a few hundredths of a pixel where
the detected keypoints are off by tenths, failed tracks are NaN, and the pipeline carries them in
the estimator's pixels without changing F; a calibrated stream's correction window fits them."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from sepfm_ros.geometry.calibrated.calibration_check import MonitorConfig
from sepfm_ros.geometry.calibrated.camera import camera_model, undistort_points
from sepfm_ros.geometry.calibrated.correction import CorrectionConfig
from sepfm_ros.pipeline.calibration import StreamCalibration
from sepfm_ros.pipeline.pipeline import Pipeline, PipelineConfig
from sepfm_ros.pipeline.subpixel import refine_points_b

SHIFT = np.array([0.3, 0.45])  # px, image b = image a moved by this


def _texture(seed: int = 0, size: tuple[int, int] = (480, 640)) -> np.ndarray:
    rng = np.random.default_rng(seed)
    noise = rng.uniform(0, 255, (size[0] // 4, size[1] // 4)).astype(np.float32)
    return np.asarray(
        cv2.resize(noise, size[::-1], interpolation=cv2.INTER_CUBIC).clip(0, 255)
    ).astype(np.uint8)


def _shifted(image: np.ndarray, shift: np.ndarray) -> np.ndarray:
    M = np.array([[1.0, 0.0, shift[0]], [0.0, 1.0, shift[1]]])
    return np.asarray(cv2.warpAffine(image, M, image.shape[::-1], flags=cv2.INTER_CUBIC))


def test_tracks_a_sub_pixel_shift_the_whole_pixels_miss():
    a = _texture()
    b = _shifted(a, SHIFT)
    rng = np.random.default_rng(1)
    pts_a = rng.uniform([40, 40], [600, 440], (200, 2))
    start = np.round(pts_a + SHIFT)  # whole pixels, as a keypoint at level 0
    refined = refine_points_b(a, b, pts_a, start)
    assert np.all(np.isfinite(refined))
    err = np.linalg.norm(refined - (pts_a + SHIFT), axis=1)
    assert np.median(np.linalg.norm(start - (pts_a + SHIFT), axis=1)) > 0.2
    assert np.median(err) < 0.06 and np.max(err) < 0.1


def test_colour_images_and_failed_tracks_are_nan():
    a = _texture(2)
    b = _shifted(a, SHIFT)
    flat = b.copy()
    flat[:, 320:] = 128  # no texture on the right half of b
    pts_a = np.array([[100.0, 100.0], [500.0, 300.0], [200.0, 240.0]])
    start = pts_a + SHIFT
    start[2] += [5.0, 0.0]  # a wrong match 5 px off: the track would move too far or fail
    colour = cv2.cvtColor(a, cv2.COLOR_GRAY2BGR), cv2.cvtColor(flat, cv2.COLOR_GRAY2BGR)
    refined = refine_points_b(*colour, pts_a, start)
    assert np.linalg.norm(refined[0] - (pts_a[0] + SHIFT)) < 0.05
    assert np.all(np.isnan(refined[1])) and np.all(np.isnan(refined[2]))
    assert refine_points_b(a, b, np.zeros((0, 2)), np.zeros((0, 2))).shape == (0, 2)
    # cameras of different sizes (OpenCV's tracker wants one size: padded, coordinates kept)
    small_b = b[:400, :600]
    refined_small = refine_points_b(a, small_b, pts_a[:1], start[:1])
    assert np.linalg.norm(refined_small[0] - (pts_a[0] + SHIFT)) < 0.05
    refined_big = refine_points_b(small_b, a, pts_a[:1] + SHIFT, pts_a[:1])
    assert np.linalg.norm(refined_big[0] - pts_a[0]) < 0.05
    with pytest.raises(ValueError, match="differ in length"):
        refine_points_b(a, b, pts_a, start[:2])


def _rig(size=(640, 480)):
    K = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])
    D = [-0.05, 0.01, 0.0, 0.0, 0.0]
    P_a = np.c_[K, np.zeros(3)]
    P_b = np.c_[K, [-500.0 * 0.1, 0, 0]]
    return (
        camera_model(K, D, "plumb_bob", np.eye(3), P_a, *size),
        camera_model(K, D, "plumb_bob", np.eye(3), P_b, *size),
    )


def test_pipeline_carries_them_undistorted_and_leaves_f_alone():
    a = _texture(3)
    b = _shifted(a, np.array([-12.3, 0.4]))
    cameras = _rig()
    plain = Pipeline(PipelineConfig()).process(a, b, cameras=cameras)
    tracked = Pipeline(PipelineConfig(), subpixel_b=True).process(a, b, cameras=cameras)
    assert plain.refined_b is None
    assert tracked.refined_b is not None and tracked.refined_b.shape == tracked.matches.pts_b.shape
    np.testing.assert_array_equal(plain.estimate.F, tracked.estimate.F)
    ok = np.all(np.isfinite(tracked.refined_b), axis=1)
    assert np.count_nonzero(ok) > 0.8 * len(ok)
    # in undistorted pixels of K, as matches.pts_b: the image-pixel track, undistorted
    assert tracked.image_matches is not None
    inl = tracked.estimate.inliers & ok
    image_truth = tracked.image_matches.pts_a[inl] + [-12.3, 0.4]
    want = undistort_points(cameras[1], image_truth)
    assert np.median(np.linalg.norm(tracked.refined_b[inl] - want, axis=1)) < 0.05
    assert np.median(np.linalg.norm(tracked.matches.pts_b[inl] - want, axis=1)) > 0.1
    assert "subpixel" in tracked.timings_ms


def test_calibrated_stream_window_fits_the_tracked_points():
    a = _texture(4)
    b = _shifted(a, np.array([-10.2, 0.35]))
    cameras = _rig()
    stream = StreamCalibration(True, False, MonitorConfig(), CorrectionConfig())
    stream.update(*cameras)
    result = Pipeline(PipelineConfig(), subpixel_b=True).process(a, b, cameras=stream.cameras)
    out = stream.outputs(result, 1.0)
    assert out.check is not None and out.check.usable
    (pair,) = stream.correction_window.pairs
    assert result.refined_b is not None
    ok = np.all(np.isfinite(result.refined_b), axis=1) & np.all(
        np.isfinite(result.matches.pts_a), axis=1
    )
    np.testing.assert_array_equal(pair.pts_b, result.refined_b[ok])
