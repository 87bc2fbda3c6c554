"""Camera models from CameraInfo fields: validation, undistortion round trips, rectified input."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from sepfm_ros.geometry.calibrated.camera import CalibrationError, camera_model, undistort_points

K = np.array([[520.0, 0.0, 330.0], [0.0, 515.0, 238.0], [0.0, 0.0, 1.0]])
W, H = 640, 480


def _model(D, dist="plumb_bob", **kw):
    args = dict(K=K, D=D, distortion_model=dist, R=np.eye(3), P=np.zeros(12), width=W, height=H)
    args.update(kw)
    return camera_model(**args)


def _raw_points(seed: int, n: int = 300) -> np.ndarray:
    """Pixel positions of an ideal (undistorted) camera with K, inside the image."""
    rng = np.random.default_rng(seed)
    return rng.uniform([20, 20], [W - 20, H - 20], (n, 2))


@pytest.mark.parametrize(
    ("dist", "D"),
    [
        ("plumb_bob", [-0.28, 0.09, 0.001, -0.0008, -0.012]),
        ("rational_polynomial", [-0.3, 0.1, 0.0005, 0.0003, -0.01, 0.02, -0.01, 0.003]),
        ("equidistant", [-0.02, 0.01, -0.004, 0.001]),
    ],
)
def test_undistort_round_trip(dist, D):
    model = _model(D, dist)
    ideal = _raw_points(1)
    rays = np.concatenate([ideal, np.ones((len(ideal), 1))], axis=1) @ np.linalg.inv(K).T
    zero = np.zeros(3)
    if dist == "equidistant":
        raw, _ = cv2.fisheye.projectPoints(rays.reshape(-1, 1, 3), zero, zero, K, np.array(D))
    else:
        raw, _ = cv2.projectPoints(rays, zero, zero, K, np.array(D))
    raw = raw.reshape(-1, 2)
    # distortion moves points by pixels, so the round trip is not trivially the identity
    assert np.max(np.linalg.norm(raw - ideal, axis=1)) > 5.0
    back = undistort_points(model, raw)
    assert np.max(np.linalg.norm(back - ideal, axis=1)) < 1e-3


def test_rectified_identity():
    P = np.array([[500.0, 0, 320.0, -50.0], [0, 500.0, 240.0, 0], [0, 0, 1, 0]])
    raw = _model([-0.2, 0.05, 0, 0, 0], P=P)
    rect = raw.rectified()
    assert not rect.has_distortion
    np.testing.assert_allclose(rect.K, P[:, :3])
    np.testing.assert_allclose(rect.R, np.eye(3))
    pts = _raw_points(2)
    np.testing.assert_array_equal(undistort_points(rect, pts), pts)
    zero_d = _model([0, 0, 0, 0, 0])
    np.testing.assert_array_equal(undistort_points(zero_d, pts), pts)


@pytest.mark.parametrize(
    ("kw", "reason"),
    [
        (dict(K=np.zeros(9)), "all zeros"),
        (dict(K=np.array([[np.nan, 0, 1], [0, 1, 1], [0, 0, 1]])), "NaN"),
        (dict(D=[0.1, np.inf, 0, 0, 0]), "NaN"),
        (dict(D=[0.1, 0.2, 0.3]), "coefficients"),
        (dict(distortion_model="unknown_model", D=[0.1] * 5), "not supported"),
        (dict(K=np.eye(4)), "values"),
        (dict(width=0), "not positive"),
        (dict(image_size=(1280, 720)), "640x480"),
        (dict(R=np.ones(9)), "rotation"),
    ],
)
def test_bad_calibration_clear_error(kw, reason):
    args = dict(D=[0.0] * 5)
    args.update(kw)
    with pytest.raises(CalibrationError, match=reason):
        _model(**args)


def test_zero_r_and_p_default_to_identity_and_k():
    m = _model([], "", R=np.zeros(9), P=np.zeros(12))
    np.testing.assert_allclose(m.R, np.eye(3))
    np.testing.assert_allclose(m.P[:, :3], K)
    assert m.size == (W, H)
