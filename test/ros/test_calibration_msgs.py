"""CameraInfo -> camera model, pose -> TransformStamped, check -> DiagnosticStatus and
the stamped DiagnosticArray of ~/calibration_check."""

from __future__ import annotations

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from scipy.spatial.transform import Rotation
from sensor_msgs.msg import CameraInfo
from std_msgs.msg import Header

from sepfm_ros.geometry.calibrated.calibration_check import WARN, CalibrationStatus
from sepfm_ros.geometry.calibrated.camera import CalibrationError
from sepfm_ros.geometry.calibrated.pose import RelativePose
from sepfm_ros.ros.msgs.calibration import (
    calibration_check_message,
    calibration_check_statuses,
    calibration_error_status,
    calibration_status,
    camera_info_from_model,
    camera_model_from_info,
    relative_transform,
)
from sepfm_ros.ros.msgs.diagnostics import status_values

K = [718.856, 0.0, 607.1928, 0.0, 718.856, 185.2157, 0.0, 0.0, 1.0]


def _info(**kw) -> CameraInfo:
    msg = CameraInfo(width=1241, height=376, distortion_model="plumb_bob", d=[0.0] * 5)
    msg.k = K
    msg.r = [1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0]
    msg.p = [718.856, 0, 607.1928, -386.1448, 0, 718.856, 185.2157, 0, 0, 0, 1.0, 0]
    for k, v in kw.items():
        setattr(msg, k, v)
    return msg


def test_camera_info_to_model():
    m = camera_model_from_info(_info(), image_size=(1241, 376))
    assert m.size == (1241, 376)
    np.testing.assert_allclose(m.K, np.reshape(K, (3, 3)))
    assert m.P[0, 3] == pytest.approx(-386.1448)


@pytest.mark.parametrize(
    ("kw", "d_count"),
    [
        (dict(), 5),
        (dict(d=[-0.3, 0.1, 0.001, -0.002, 0.0]), 5),
        (dict(distortion_model="equidistant", d=[0.1, -0.02, 0.003, 0.0]), 4),
        (dict(distortion_model="", d=[]), 5),  # no distortion: written as plumb_bob zeros
    ],
)
def test_camera_info_from_model_round_trip(kw, d_count):
    rotated = Rotation.from_euler("x", 0.5, degrees=True).as_matrix()
    model = camera_model_from_info(_info(**kw, r=list(rotated.ravel())), image_size=(1241, 376))
    hdr = Header(frame_id="right_camera_optical_frame")
    hdr.stamp.sec, hdr.stamp.nanosec = 17, 250
    msg = camera_info_from_model(model, hdr)
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (17, 250)
    assert msg.header.frame_id == "right_camera_optical_frame"
    assert (msg.width, msg.height) == (1241, 376) and len(msg.d) == d_count
    back = camera_model_from_info(msg, image_size=(1241, 376))
    assert back.distortion_model == model.distortion_model
    for field in ("K", "R", "P"):
        np.testing.assert_allclose(getattr(back, field), getattr(model, field), atol=1e-12)
    np.testing.assert_allclose(back.D[: model.D.size], model.D)
    assert not np.any(back.D[model.D.size :])


@pytest.mark.parametrize(
    ("kw", "size", "reason"),
    [
        (dict(k=[0.0] * 9), None, "all zeros"),
        (dict(d=[float("nan")] * 5), None, "NaN"),
        (dict(), (640, 480), "1241x376"),
        (dict(binning_x=2), None, "binning"),
        (dict(distortion_model="weird"), None, "not supported"),
    ],
)
def test_bad_camera_info(kw, size, reason):
    with pytest.raises(CalibrationError, match=reason):
        camera_model_from_info(_info(**kw), image_size=size)


def test_relative_transform_is_b_in_a():
    R = Rotation.from_euler("xyz", [2.0, -5.0, 10.0], degrees=True).as_matrix()
    t = np.array([-0.5, 0.1, 0.2])
    pose = RelativePose(R, t, 1.0, 100)
    header = Header(frame_id="ignored")
    header.stamp.sec, header.stamp.nanosec = 12, 345
    msg = relative_transform(pose, header, "left_camera_optical_frame", "right_optical")
    assert msg.header.frame_id == "left_camera_optical_frame"
    assert msg.child_frame_id == "right_optical"
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (12, 345)
    q = msg.transform.rotation
    R_ba = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
    tr = msg.transform.translation
    p_ba = np.array([tr.x, tr.y, tr.z])
    # maps b-coordinates to a-coordinates: X_a = R_ba X_b + p_ba inverts X_b = R X_a + t
    X_a = np.array([0.3, -0.2, 4.0])
    np.testing.assert_allclose(R_ba @ (R @ X_a + t) + p_ba, X_a, atol=1e-9)


def test_calibration_status_message():
    st = CalibrationStatus(WARN, "stereo calibration drifting", {"epipolar_median_px": 1.5})
    msg = calibration_status(st, "/rig_a/sepfm")
    assert msg.name == "/rig_a/sepfm: calibration" and msg.level == DiagnosticStatus.WARN
    assert status_values(msg)["epipolar_median_px"] == "1.5"
    err = calibration_error_status(CalibrationError("K is all zeros"), "/rig_a/sepfm")
    assert err.level == DiagnosticStatus.ERROR and "K is all zeros" in err.message
    assert err.name == "/rig_a/sepfm: calibration"


def test_calibration_check_message_is_stamped_with_the_pair():
    st = calibration_status(CalibrationStatus(WARN, "drifting", {}), "/sepfm")
    header = Header(frame_id="left_camera_optical_frame")
    header.stamp.sec, header.stamp.nanosec = 1700000000, 100000000
    msg = calibration_check_message(header, st)
    assert isinstance(msg, DiagnosticArray)
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (1700000000, 100000000)
    assert msg.header.frame_id == "left_camera_optical_frame"
    assert list(msg.status) == [st]
    header.stamp.sec = 5  # a copy of the header, not the caller's object
    assert msg.header.stamp.sec == 1700000000
    # readers take the array and 0.1.0's bare status alike
    assert calibration_check_statuses(msg) == [st]
    assert calibration_check_statuses(st) == [st]


def _pose_with_covariance():
    from sepfm_ros.geometry.calibrated.pose import pose_from_projections, relative_pose
    from sepfm_ros.geometry.synthetic import make_pair

    pair = make_pair(n_inliers=150, noise=0.5, seed=2)
    K_a, K_b, _, _ = pose_from_projections(pair.P1, pair.P2)
    from sepfm_ros.geometry import estimate_fundamental

    est = estimate_fundamental(pair.pts1, pair.pts2, pair.image_size, seed=0)
    pose = relative_pose(est.F, pair.pts1, pair.pts2, K_a, K_b, est.inliers)
    assert pose.ok and pose.covariance is not None
    return pose


def test_pose_messages_frames_units_and_covariance():
    from sepfm_ros.geometry.calibrated.pose_covariance import pose_in_a_covariance
    from sepfm_ros.ros.msgs.calibration import (
        angular_velocity_message,
        relative_pose_message,
        translation_direction_message,
    )

    pose = _pose_with_covariance().scaled(0.5)
    header = Header(frame_id="ignored")
    header.stamp.sec = 7
    msg = relative_pose_message(pose, header, "left_optical")
    tf = relative_transform(pose, header, "left_optical", "right_optical")
    assert msg.header.frame_id == "left_optical" and msg.header.stamp.sec == 7
    p = msg.pose.pose.position
    assert [p.x, p.y, p.z] == [
        tf.transform.translation.x,
        tf.transform.translation.y,
        tf.transform.translation.z,
    ]
    C = np.reshape(msg.pose.covariance, (6, 6))
    assert np.allclose(C, pose_in_a_covariance(pose.covariance, 0.5))
    assert np.all(np.linalg.eigvalsh(C) > 0)
    # a moving camera: rotation over the seconds between the frames, in rad/s
    twist = angular_velocity_message(pose, header, "camera_optical", 0.1)
    w = twist.twist.twist.angular
    expected = Rotation.from_matrix(pose.R.T).as_rotvec() / 0.1
    assert np.allclose([w.x, w.y, w.z], expected)
    Ct = np.reshape(twist.twist.covariance, (6, 6))
    assert np.allclose(Ct[3:, 3:], pose.covariance.rotation_in_a() / 0.01)
    assert np.all(np.linalg.eigvalsh(Ct) > 0) and twist.header.frame_id == "camera_optical"
    assert angular_velocity_message(pose, header, "camera_optical", 0.0) is None
    d = translation_direction_message(pose, header, "camera_optical").vector
    expected_d = -pose.R.T @ pose.t / np.linalg.norm(pose.t)
    assert np.allclose([d.x, d.y, d.z], expected_d)
