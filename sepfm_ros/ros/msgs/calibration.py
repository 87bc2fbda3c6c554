"""ROS messages of calibrated estimation: CameraInfo in, pose and calibration check out.

- :func:`camera_model_from_info`: ``sensor_msgs/CameraInfo`` (rclpy or rosbags message) ->
  validated :class:`~sepfm_ros.geometry.calibrated.camera.CameraModel` (CalibrationError with
  the reason); :func:`camera_info_from_model` the reverse (a model -> ``CameraInfo`` under a
  given header), for the corrected calibration the node publishes and sends to a driver.
- :func:`relative_transform`: a relative pose -> ``geometry_msgs/TransformStamped`` of camera b
  in camera a's optical frame (header = a's frame and the pair's stamp, child = b's frame).
- :func:`relative_pose_message`: the same pose with its covariance ->
  ``geometry_msgs/PoseWithCovarianceStamped`` (stereo, ``~/relative_pose``);
- :func:`angular_velocity_message` and :func:`translation_direction_message`: one moving
  camera's rotation between two frames as an angular velocity with covariance
  (``geometry_msgs/TwistWithCovarianceStamped``, ``~/angular_velocity``) and the unit direction
  of its motion (``geometry_msgs/Vector3Stamped``, ``~/translation_direction``);
- :func:`calibration_status`: the stereo check's decision -> ``diagnostic_msgs/DiagnosticStatus``
  named ``<node FQN>: calibration``, with the correction's state (:func:`correction_values`).
- :func:`calibration_check_message`: that status stamped with its pair's header, as the
  ``diagnostic_msgs/DiagnosticArray`` of ``~/calibration_check``.
- :func:`calibration_check_statuses`: the statuses of a ``~/calibration_check`` message of either
  type (the DiagnosticArray, or the bare DiagnosticStatus that sepfm_ros 0.1.0 wrote), for readers.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import (
    Point,
    Pose,
    PoseWithCovariance,
    PoseWithCovarianceStamped,
    Quaternion,
    Transform,
    TransformStamped,
    Twist,
    TwistWithCovariance,
    TwistWithCovarianceStamped,
    Vector3,
    Vector3Stamped,
)
from scipy.spatial.transform import Rotation
from std_msgs.msg import Header

from sepfm_ros.geometry.calibrated.calibration_check import CalibrationStatus
from sepfm_ros.geometry.calibrated.camera import CalibrationError, CameraModel, camera_model
from sepfm_ros.geometry.calibrated.correction import CorrectionResult
from sepfm_ros.geometry.calibrated.pose import RelativePose, pose_of_b_in_a
from sepfm_ros.geometry.calibrated.pose_covariance import pose_in_a_covariance
from sepfm_ros.ros.msgs.diagnostics import diagnostic_array, health_status, status_name
from sepfm_ros.ros.msgs.headers import copy_header

CALIBRATION_TASK = "calibration"


def camera_model_from_info(msg: Any, image_size: tuple[int, int] | None = None) -> CameraModel:
    """A validated camera model from a ``sensor_msgs/CameraInfo``.

    Args:
        msg: the CameraInfo (rclpy or rosbags message: fields k, d, distortion_model, r, p,
            width, height, binning_x/y, roi).
        image_size: (width, height) of the images it is paired with, when known.
    Raises:
        CalibrationError: zero K, NaN, wrong sizes, unknown distortion model, binning or a
            region of interest (not supported), calibration for another image size.
    """
    bx, by = int(getattr(msg, "binning_x", 0)), int(getattr(msg, "binning_y", 0))
    if bx > 1 or by > 1:
        raise CalibrationError(f"binning {bx}x{by} is not supported")
    roi = getattr(msg, "roi", None)
    if roi is not None and int(roi.width) and int(roi.height):
        full = (int(roi.x_offset), int(roi.y_offset), int(roi.width), int(roi.height))
        if full != (0, 0, int(msg.width), int(msg.height)):
            raise CalibrationError(f"a region of interest {full} is not supported")
    return camera_model(
        msg.k, msg.d, msg.distortion_model, msg.r, msg.p, msg.width, msg.height, image_size
    )


#: zero distortion coefficients written for a model without any, per distortion model (the
#: counts image_geometry and camera_calibration_parsers expect)
ZERO_DISTORTION = {"plumb_bob": 5, "rational_polynomial": 8, "equidistant": 4}


def camera_info_from_model(model: CameraModel, header: Header) -> Any:
    """A ``sensor_msgs/CameraInfo`` of ``model`` under ``header`` (copied): width, height,
    distortion_model, d (zeros of the model's usual count when it has none), k, r, p row-major;
    no binning, no region of interest. :func:`camera_model_from_info` of it gives ``model``
    back."""
    from sensor_msgs.msg import CameraInfo

    D = np.asarray(model.D, np.float64).reshape(-1)
    if D.size == 0:
        D = np.zeros(ZERO_DISTORTION.get(model.distortion_model, 5))
    msg = CameraInfo(header=copy_header(header), width=int(model.width), height=int(model.height))
    msg.distortion_model = model.distortion_model
    msg.d = [float(v) for v in D]
    msg.k = [float(v) for v in np.asarray(model.K, np.float64).reshape(-1)]
    msg.r = [float(v) for v in np.asarray(model.R, np.float64).reshape(-1)]
    msg.p = [float(v) for v in np.asarray(model.P, np.float64).reshape(-1)]
    return msg


def relative_transform(
    pose: RelativePose, header: Header, frame_a: str, frame_b: str
) -> TransformStamped:
    """The pose of camera b in camera a's optical frame as a TransformStamped.

    Args:
        pose: (R, t) with ``X_b = R X_a + t``; t unit (motion) or metres (stereo, scaled).
        header: the pair's header (its stamp is used); ``frame_id`` is set to ``frame_a``.
        frame_a, frame_b: optical frame ids of camera a (parent) and b (child).
    """
    R_ba, p_ba = pose_of_b_in_a(pose.R, pose.t)
    x, y, z, w = Rotation.from_matrix(R_ba).as_quat()
    hdr = copy_header(header)
    hdr.frame_id = frame_a
    return TransformStamped(
        header=hdr,
        child_frame_id=frame_b,
        transform=Transform(
            translation=Vector3(x=float(p_ba[0]), y=float(p_ba[1]), z=float(p_ba[2])),
            rotation=Quaternion(x=float(x), y=float(y), z=float(z), w=float(w)),
        ),
    )


# variance ((m/s)^2) of the angular-velocity message's linear part: the camera's velocity is not
# measured by one camera's two frames (robot_localization: fuse only vroll, vpitch, vyaw)
UNKNOWN_VELOCITY_VARIANCE = 1e6


def _stamped(header: Header, frame_id: str) -> Header:
    hdr = copy_header(header)
    hdr.frame_id = frame_id
    return hdr


def relative_pose_message(
    pose: RelativePose, header: Header, frame_a: str
) -> PoseWithCovarianceStamped | None:
    """The pose of camera b in camera a's optical frame with its covariance (stereo: t in
    metres of the calibrated baseline), or None when the pose has no covariance.

    Covariance: row-major 6x6 over (x, y, z) in metres and rotations about a's fixed x, y, z
    axes in radians (:func:`~sepfm_ros.geometry.calibrated.pose_covariance.pose_in_a_covariance`).
    """
    if pose.covariance is None:
        return None
    R_ba, p_ba = pose_of_b_in_a(pose.R, pose.t)
    x, y, z, w = Rotation.from_matrix(R_ba).as_quat()
    cov = pose_in_a_covariance(pose.covariance, float(np.linalg.norm(pose.t)))
    return PoseWithCovarianceStamped(
        header=_stamped(header, frame_a),
        pose=PoseWithCovariance(
            pose=Pose(
                position=Point(x=float(p_ba[0]), y=float(p_ba[1]), z=float(p_ba[2])),
                orientation=Quaternion(x=float(x), y=float(y), z=float(z), w=float(w)),
            ),
            covariance=[float(v) for v in cov.ravel()],
        ),
    )


def angular_velocity_message(
    pose: RelativePose, header: Header, frame: str, dt_s: float
) -> TwistWithCovarianceStamped | None:
    """One camera's angular velocity (rad/s) between frames ``dt_s`` seconds apart, in its
    optical frame, with covariance (rad/s)^2; None without a covariance or a positive dt.

    angular = rotvec(R_ba) / dt, R_ba = R^T the rotation of the later frame in the earlier one
    (the axis is the same in both frames); linear = 0 with variance
    :data:`UNKNOWN_VELOCITY_VARIANCE` (not measured).
    """
    if pose.covariance is None or not dt_s > 0:
        return None
    w = Rotation.from_matrix(pose.R.T).as_rotvec() / dt_s
    cov = np.zeros((6, 6))
    cov[:3, :3] = np.eye(3) * UNKNOWN_VELOCITY_VARIANCE
    cov[3:, 3:] = pose.covariance.rotation_in_a() / dt_s**2
    return TwistWithCovarianceStamped(
        header=_stamped(header, frame),
        twist=TwistWithCovariance(
            twist=Twist(angular=Vector3(x=float(w[0]), y=float(w[1]), z=float(w[2]))),
            covariance=[float(v) for v in ((cov + cov.T) / 2).ravel()],
        ),
    )


def translation_direction_message(pose: RelativePose, header: Header, frame: str) -> Vector3Stamped:
    """The unit direction (no unit: the length is unknown) of the later camera centre seen
    from the earlier one, in the camera's optical frame: ``-R^T t``."""
    d = -pose.R.T @ pose.t
    d = d / np.linalg.norm(d)
    return Vector3Stamped(
        header=_stamped(header, frame),
        vector=Vector3(x=float(d[0]), y=float(d[1]), z=float(d[2])),
    )


AXES = ("pitch", "yaw", "roll")  # the correction's rotation vector components in b's optical axes


def correction_values(result: CorrectionResult | None) -> dict[str, Any]:
    """The correction's state as diagnostic values: ``correction`` (one line: the per-axis
    correction with its 95 % interval and the pairs used, or ``none: <why>``); with a
    correction also ``correction_<axis>_deg`` and ``correction_<axis>_interval_deg`` for
    pitch, yaw and roll (yaw's is the free fit's when yaw is kept), ``correction_yaw_corrected``
    and ``correction_pairs``. Empty for None (no rig)."""
    if result is None:
        return {}
    fix = result.correction
    if fix is None:
        return {"correction": f"none: {result.reason}"}
    parts = []
    values: dict[str, Any] = {}
    for k, axis in enumerate(AXES):
        value = float(fix.axes_deg[k])
        if axis == "yaw" and not fix.yaw_determined:
            value = float(fix.yaw_estimate_deg)
            parts.append(f"yaw kept ({value:+.3f} ± {fix.interval_deg[k]:.3f})")
        else:
            parts.append(f"{axis} {value:+.3f} ± {fix.interval_deg[k]:.3f}")
        values[f"correction_{axis}_deg"] = round(value, 4)
        values[f"correction_{axis}_interval_deg"] = round(float(fix.interval_deg[k]), 4)
    values["correction_yaw_corrected"] = int(fix.yaw_determined)
    values["correction_pairs"] = fix.n_pairs
    text = ", ".join(parts) + f" deg (95 %) from {fix.n_pairs} pairs"
    return {"correction": text, **values}


def calibration_status(
    status: CalibrationStatus,
    node_fqn: str,
    hardware_id: str = "",
    correction: CorrectionResult | None = None,
) -> DiagnosticStatus:
    """The stereo calibration check as ``DiagnosticStatus`` named ``<node FQN>: calibration``,
    with the ``correction``'s state after the same pair (:func:`correction_values`)."""
    return health_status(
        status_name(node_fqn, CALIBRATION_TASK),
        bytes([status.level]),
        status.message,
        {**status.values, **correction_values(correction)},
        hardware_id,
    )


def calibration_error_status(
    error: CalibrationError, node_fqn: str, hardware_id: str = ""
) -> DiagnosticStatus:
    """ERROR status for unusable calibration input; the node keeps estimating F without it."""
    return health_status(
        status_name(node_fqn, CALIBRATION_TASK),
        DiagnosticStatus.ERROR,
        f"camera_info unusable, estimating without calibration: {error}",
        {},
        hardware_id,
    )


def calibration_check_message(header: Header, status: DiagnosticStatus) -> DiagnosticArray:
    """``~/calibration_check``: the check's ``status`` for one pair, stamped with the pair's
    ``header`` (copied: the left or current image's stamp, camera a's frame id), so a consumer
    knows which pair the decision includes, as for ``~/estimate``."""
    return diagnostic_array(header, [status])


def calibration_check_statuses(msg: DiagnosticArray | DiagnosticStatus) -> list[DiagnosticStatus]:
    """The statuses of a ``~/calibration_check`` message of either type: a DiagnosticArray's
    statuses, or a bare DiagnosticStatus (as sepfm_ros 0.1.0 published and wrote it) alone."""
    if isinstance(msg, DiagnosticArray):
        return list(msg.status)
    return [msg]
