"""The corrected calibration's parts without DDS: the calibration a driver stores for rectified
input (:func:`~sepfm_ros.ros.node.corrected.driver_models`) and the correction's diagnostic
values (:func:`~sepfm_ros.ros.msgs.calibration.correction_values`)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from sepfm_ros.geometry.calibrated.camera import camera_model
from sepfm_ros.geometry.calibrated.correction import CorrectionResult, RigCorrection
from sepfm_ros.geometry.calibrated.stereo_rectify import corrected_models
from sepfm_ros.ros.msgs.calibration import correction_values
from sepfm_ros.ros.node.corrected import driver_models

SIZE = (640, 480)


def _raw_rig():
    """A converged raw rig with distortion and its ROS rectification (cv2.stereoRectify)."""
    K_l = np.array([[600.0, 0, 318], [0, 602, 243], [0, 0, 1]])
    K_r = np.array([[610.0, 0, 325], [0, 609, 238], [0, 0, 1]])
    D_l = np.array([-0.21, 0.05, 0.001, -0.0005, 0.0])
    D_r = np.array([-0.19, 0.04, -0.0007, 0.0009, 0.0])
    R = cv2.Rodrigues(np.radians([0.4, -1.2, 0.3]))[0]
    t = np.array([-0.12, 0.003, 0.002])
    R1, R2, P1, P2 = cv2.stereoRectify(
        K_l, D_l, K_r, D_r, SIZE, R, t.reshape(3, 1), flags=cv2.CALIB_ZERO_DISPARITY, alpha=0
    )[:4]
    left = camera_model(K_l, D_l, "plumb_bob", R1, P1, *SIZE)
    right = camera_model(K_r, D_r, "plumb_bob", R2, P2, *SIZE)
    return left, right


def _rectify(points, model):
    """Pixels of ``model``'s raw image -> its rectified pixels (image_proc's mapping)."""
    out = cv2.undistortPoints(points.reshape(-1, 1, 2), model.K, model.D, R=model.R, P=model.P)
    return out.reshape(-1, 2)


def test_driver_models_of_rectified_input_compose_both_rectifications():
    raw = _raw_rig()
    stale = (raw[0].rectified(), raw[1].rectified())
    baseline = -raw[1].P[0, 3] / raw[1].P[0, 0]
    knock = cv2.Rodrigues(np.radians([0.3, 0.0, -0.2]))[0]
    t = knock @ np.array([-baseline, 0.0, 0.0])  # b turned about its own centre
    corrected = corrected_models(*raw, knock, t, True)  # describes the stale-rectified images
    stored = driver_models(corrected, raw, True)
    rng = np.random.default_rng(3)
    points = rng.uniform((20, 20), (620, 460), (200, 2))
    for k in range(2):
        assert np.array_equal(stored[k].K, raw[k].K) and np.array_equal(stored[k].D, raw[k].D)
        # raw pixels rectified with the stored calibration = the stale rectified pixels
        # rectified again with the corrected camera_info of the rectified images
        direct = _rectify(points, stored[k])
        twice = _rectify(_rectify(points, raw[k]), corrected[k])
        np.testing.assert_allclose(direct, twice, atol=1e-6)
        assert stale[k].K == pytest.approx(corrected[k].K)
    assert driver_models(corrected, raw, False) is corrected


def test_correction_values_say_the_correction_or_why_none():
    assert correction_values(None) == {}
    none = correction_values(CorrectionResult(None, "too few pairs (4 of 10)"))
    assert none == {"correction": "none: too few pairs (4 of 10)"}
    fix = RigCorrection(
        R=np.eye(3),
        t=np.array([-0.5, 0.0, 0.0]),
        axes_deg=np.array([0.51, 0.0, -0.02]),
        interval_deg=np.array([0.01, 0.2, 0.03]),
        yaw_determined=False,
        n_pairs=20,
        n_matches=4000,
        yaw_estimate_deg=0.31,
    )
    values = correction_values(CorrectionResult(fix, "corrected"))
    assert values["correction"] == (
        "pitch +0.510 ± 0.010, yaw kept (+0.310 ± 0.200), roll -0.020 ± 0.030 deg (95 %) "
        "from 20 pairs"
    )
    assert values["correction_pitch_deg"] == 0.51 and values["correction_yaw_deg"] == 0.31
    assert values["correction_roll_interval_deg"] == 0.03
    assert values["correction_yaw_corrected"] == 0 and values["correction_pairs"] == 20
