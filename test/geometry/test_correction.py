"""Stereo correction: the rotation of a knocked camera b from a window of pairs, and the
camera_info of the corrected rectification."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from sepfm_ros.geometry.calibrated.calibration_check import StereoCalibration
from sepfm_ros.geometry.calibrated.camera import camera_model, undistort_points
from sepfm_ros.geometry.calibrated.correction import (
    CorrectionConfig,
    CorrectionWindow,
    estimate_correction,
)
from sepfm_ros.geometry.calibrated.stereo_rectify import corrected_models

SIZE = (1280, 720)
K_A = np.array([[700.0, 0, 630.0], [0, 705.0, 370.0], [0, 0, 1]])
K_B = np.array([[690.0, 0, 650.0], [0, 695.0, 355.0], [0, 0, 1]])
D = np.array([-0.2, 0.05, 0.001, -0.001, 0.0])
R0 = cv2.Rodrigues(np.radians([0.8, -1.5, 0.6]))[0]
T0 = np.array([-0.12, 0.004, 0.006])


def _models():
    R1, R2, P1, P2 = cv2.stereoRectify(K_A, D, K_B, D, SIZE, R0, T0.reshape(3, 1), alpha=0)[:4]
    return (
        camera_model(K_A, D, "plumb_bob", R1, P1, *SIZE),
        camera_model(K_B, D, "plumb_bob", R2, P2, *SIZE),
    )


def _rig() -> StereoCalibration:
    return StereoCalibration.from_models(*_models())


def _pair(delta_deg, seed: int, n: int = 400, noise: float = 0.3, spread: float = 1.0):
    """Undistorted matches of random points; camera b turned by delta about its own centre."""
    rng = np.random.default_rng(seed)
    X = np.stack(
        [rng.uniform(-6, 6, n) * spread, rng.uniform(-2, 2, n) * spread, rng.uniform(3, 30, n)],
        axis=1,
    )
    dR = cv2.Rodrigues(np.radians(np.asarray(delta_deg, float)).reshape(3, 1))[0]
    xa, _ = cv2.projectPoints(X, np.zeros(3), np.zeros(3), K_A, D)
    xb, _ = cv2.projectPoints(X, cv2.Rodrigues(dR @ R0)[0], dR @ T0, K_B, D)
    xa = xa.reshape(-1, 2) + rng.normal(0, noise, (n, 2))
    xb = xb.reshape(-1, 2) + rng.normal(0, noise, (n, 2))
    inside = np.all((xa > 0) & (xa < SIZE) & (xb > 0) & (xb < SIZE), axis=1)
    calib = _rig()
    return undistort_points(calib.model_a, xa[inside]), undistort_points(calib.model_b, xb[inside])


def _window(delta_deg, pairs: int, seed: int = 0, **kw) -> CorrectionWindow:
    window = CorrectionWindow(40)
    for k in range(pairs):
        window.add(*_pair(delta_deg, seed * 1000 + k, **kw))
    return window


@pytest.mark.parametrize("axis", [0, 2])
def test_knocked_camera_is_corrected(axis):
    delta = np.zeros(3)
    delta[axis] = 0.5
    calib = _rig()
    result = estimate_correction(calib, _window(delta, 20), CorrectionConfig())
    fix = result.correction
    assert fix is not None, result.reason
    assert fix.axes_deg[axis] == pytest.approx(0.5, abs=0.02)
    assert fix.n_pairs == 20 and fix.n_matches > 20 * 200
    # the interval covers the truth on the corrected axis and is narrow
    assert abs(fix.axes_deg[axis] - 0.5) <= fix.interval_deg[axis] + 0.005
    assert fix.interval_deg[axis] < 0.03
    # b turned about its own centre: the rotation and the translation both turn
    dR = cv2.Rodrigues(np.radians(delta).reshape(3, 1))[0]
    err = np.degrees(np.linalg.norm(cv2.Rodrigues(fix.R @ (dR @ calib.R).T)[0]))
    assert err < 0.03 + abs(fix.axes_deg[1])
    assert np.linalg.norm(fix.t) == pytest.approx(np.linalg.norm(calib.t))


def test_too_few_pairs_give_no_correction():
    result = estimate_correction(_rig(), _window([0.5, 0, 0], 3), CorrectionConfig())
    assert result.correction is None
    assert "too few pairs" in result.reason


def test_clean_rig_gets_no_correction():
    result = estimate_correction(_rig(), _window([0, 0, 0], 40), CorrectionConfig())
    assert result.correction is None, result.reason
    assert "no correction needed" in result.reason


def test_bad_pairs_are_dropped():
    calib = _rig()
    window = _window([0.0, 0.0, 0.5], 20)
    rng = np.random.default_rng(7)
    for _ in range(4):  # pairs of wrong matches (a repeated texture, a moving object)
        pa, pb = _pair([0.0, 0.0, 0.5], int(rng.integers(1 << 30)))
        window.add(pa, pb + np.array([0.0, 25.0]))
    fix = estimate_correction(calib, window, CorrectionConfig()).correction
    assert fix is not None
    assert fix.axes_deg[2] == pytest.approx(0.5, abs=0.02)
    assert fix.n_pairs <= 20


def test_matches_in_a_small_patch_give_no_correction():
    result = estimate_correction(_rig(), _window([0.5, 0, 0], 20, spread=0.05), CorrectionConfig())
    assert result.correction is None
    assert "degenerate" in result.reason


def test_corrected_rectification_aligns_rows():
    """Rectified with the corrected camera_info the knocked rig's rows align again."""
    model_a, model_b = _models()
    calib = _rig()
    delta = np.array([0.4, 0.0, -0.6])
    fix = estimate_correction(calib, _window(delta, 20), CorrectionConfig()).correction
    assert fix is not None
    new_a, new_b = corrected_models(model_a, model_b, fix.R, fix.t, rectified=False)
    np.testing.assert_array_equal(new_a.K, model_a.K)
    np.testing.assert_array_equal(new_b.D, model_b.D)
    assert new_b.P[0, 3] == pytest.approx(model_b.P[0, 3], rel=1e-9)
    np.testing.assert_allclose(new_b.P[:, :3], model_b.P[:, :3])
    pa, pb = _pair(delta, 99, noise=0.0)

    def rect(model, pts):
        out = cv2.undistortPoints(pts.reshape(-1, 1, 2), model.K, None, R=model.R, P=model.P)
        return out.reshape(-1, 2)

    stale = np.abs(rect(model_a, pa)[:, 1] - rect(model_b, pb)[:, 1])
    fixed = np.abs(rect(new_a, pa)[:, 1] - rect(new_b, pb)[:, 1])
    assert np.median(stale) > 3.0
    assert np.median(fixed) < 0.1


def test_corrected_models_of_rectified_images():
    """Rectified input: K = old P[:, :3], D = 0; R turns the stale rectified frame."""
    model_a, model_b = _models()
    calib = StereoCalibration.from_models(model_a, model_b, rectified=True)
    dR = cv2.Rodrigues(np.radians([0.3, 0.0, 0.2]).reshape(3, 1))[0]
    new_a, new_b = corrected_models(model_a, model_b, dR @ calib.R, dR @ calib.t, rectified=True)
    np.testing.assert_allclose(new_b.K, model_b.P[:, :3])
    assert not np.any(new_b.D)
    # the two rectified frames end parallel: R_b' (dR) R_a'^T = I
    np.testing.assert_allclose(new_b.R @ dR @ new_a.R.T, np.eye(3), atol=1e-9)


def test_bad_config_is_refused():
    with pytest.raises(ValueError, match="min_pairs"):
        CorrectionConfig(window=5, min_pairs=10)
    with pytest.raises(ValueError, match="differ in length"):
        CorrectionWindow().add(np.zeros((30, 2)), np.zeros((29, 2)))
