"""Stereo calibration check: per-pair figures against a calibrated rig, and the window monitor."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from sepfm_ros.geometry.calibrated.calibration_check import (
    ERROR,
    OK,
    STALE,
    WARN,
    CalibrationMonitor,
    MonitorConfig,
    PairCheck,
    StereoCalibration,
    check_pair,
)
from sepfm_ros.geometry.calibrated.camera import camera_model, undistort_points

SIZE = (1280, 720)
K_A = np.array([[700.0, 0, 630.0], [0, 705.0, 370.0], [0, 0, 1]])
K_B = np.array([[690.0, 0, 650.0], [0, 695.0, 355.0], [0, 0, 1]])
D = np.array([-0.2, 0.05, 0.001, -0.001, 0.0])
R0 = cv2.Rodrigues(np.radians([0.8, -1.5, 0.6]))[0]
T0 = np.array([-0.12, 0.004, 0.006])


def _rig() -> StereoCalibration:
    R1, R2, P1, P2 = cv2.stereoRectify(K_A, D, K_B, D, SIZE, R0, T0.reshape(3, 1), alpha=0)[:4]
    ma = camera_model(K_A, D, "plumb_bob", R1, P1, *SIZE)
    mb = camera_model(K_B, D, "plumb_bob", R2, P2, *SIZE)
    return StereoCalibration.from_models(ma, mb)


def _raw_matches(delta_deg, seed: int, n: int = 400, noise: float = 0.3):
    """Distorted pixel matches of random points seen by the rig, camera b rotated by delta."""
    rng = np.random.default_rng(seed)
    X = np.stack(
        [rng.uniform(-6, 6, n), rng.uniform(-2, 2, n), rng.uniform(3, 30, n)], axis=1
    )  # in a's frame
    dR = cv2.Rodrigues(np.radians(delta_deg).reshape(3, 1))[0]
    R_b = dR @ R0
    xa, _ = cv2.projectPoints(X, np.zeros(3), np.zeros(3), K_A, D)
    xb, _ = cv2.projectPoints(X, cv2.Rodrigues(R_b)[0], dR @ T0, K_B, D)
    xa = xa.reshape(-1, 2) + rng.normal(0, noise, (n, 2))
    xb = xb.reshape(-1, 2) + rng.normal(0, noise, (n, 2))
    inside = np.all((xa > 0) & (xa < SIZE) & (xb > 0) & (xb < SIZE), axis=1)
    return xa[inside], xb[inside]


def _check(delta_deg, seed=0) -> PairCheck:
    calib = _rig()
    xa, xb = _raw_matches(np.asarray(delta_deg, dtype=float), seed)
    pa = undistort_points(calib.model_a, xa)
    pb = undistort_points(calib.model_b, xb)
    return check_pair(calib, pa, pb, np.ones(len(pa), bool))


def test_clean_rig_agrees_with_calibration():
    c = _check([0.0, 0.0, 0.0])
    assert c.usable and c.n_inliers > 200
    assert c.epipolar_median_px < 0.4
    assert c.rotation_error_deg < 0.05
    assert np.all(np.abs(c.rotation_axes_deg) < 0.1)


@pytest.mark.parametrize("axis", [0, 2])
def test_rotated_camera_is_measured(axis):
    delta = np.zeros(3)
    delta[axis] = 0.3
    c = _check(delta)
    assert c.epipolar_median_px > 0.6
    # the measured rotation is b's extra rotation, in b's optical axes
    assert c.rotation_axes_deg[axis] == pytest.approx(0.3, abs=0.05)
    assert c.rotation_error_deg == pytest.approx(0.3, abs=0.05)


def test_distortion_must_be_removed():
    """Without undistortion the same clean matches look decalibrated: the model is used."""
    calib = _rig()
    xa, xb = _raw_matches(np.zeros(3), 1)
    everything = np.ones(len(xa), bool)
    raw = check_pair(calib, xa, xb, everything)
    pa, pb = undistort_points(calib.model_a, xa), undistort_points(calib.model_b, xb)
    clean = check_pair(calib, pa, pb, everything)
    assert raw.epipolar_p90_px > 1.2 * clean.epipolar_p90_px, (raw, clean)
    assert np.all(np.abs(clean.rotation_axes_deg) < 0.05)
    assert np.max(np.abs(raw.rotation_axes_deg)) > 0.5


def test_too_few_inliers_unusable_and_bad_lengths():
    calib = _rig()
    xa, xb = _raw_matches(np.zeros(3), 2)
    mask = np.zeros(len(xa), bool)
    mask[:10] = True
    c = check_pair(calib, xa, xb, mask, min_inliers=30)
    assert not c.usable and np.isnan(c.epipolar_median_px)
    with pytest.raises(ValueError, match="differ in length"):
        check_pair(calib, xa, xb[:-1], np.ones(len(xa), bool))


def _pc(epi: float, rot: float, usable: bool = True) -> PairCheck:
    return PairCheck(100, epi, epi * 2, rot, np.array([rot, 0.0, 0.0]), usable)


def test_monitor_levels_and_window():
    cfg = MonitorConfig(
        window=6,
        min_pairs=3,
        warn_epipolar_px=1.0,
        error_epipolar_px=3.0,
        warn_rotation_deg=0.1,
        error_rotation_deg=0.5,
    )
    mon = CalibrationMonitor(cfg)
    assert mon.update(_pc(0.1, 0.01)).level == STALE
    assert mon.update(_pc(0.1, 0.01, usable=False)).level == STALE
    assert mon.update(_pc(0.1, 0.01)).level == STALE
    st = mon.update(_pc(0.1, 0.01))
    assert st.level == OK and st.level_name == "OK"
    assert st.values["usable_pairs"] == 3 and st.values["epipolar_median_px"] == pytest.approx(0.1)
    # one bad pair in the window does not alarm (window median)
    assert mon.update(_pc(5.0, 2.0)).level == OK
    # drift: rotation beyond WARN
    for _ in range(6):
        st = mon.update(_pc(0.2, 0.2))
    assert st.level == WARN and "drifting" in st.message
    for _ in range(6):
        st = mon.update(_pc(4.0, 0.05))
    assert st.level == ERROR and st.values["epipolar_median_px"] == pytest.approx(4.0)
    mon.reset()
    assert mon.update(_pc(0.1, 0.01)).level == STALE


def test_monitor_config_validation():
    with pytest.raises(ValueError, match="min_pairs"):
        MonitorConfig(window=3, min_pairs=5)
    with pytest.raises(ValueError, match="warn_rotation_deg"):
        MonitorConfig(warn_rotation_deg=1.0, error_rotation_deg=0.5)
