"""camera_info messages in, calibrated outputs as messages out: what the node and ``process`` do
with a stream's calibration (:class:`~sepfm_ros.pipeline.calibration.StreamCalibration`).

Per pair: :meth:`CalibratedStream.cameras` turns the latest ``CameraInfo`` of each camera into the
camera models the pipeline undistorts with (None without usable ones, with an ERROR calibration
status saying why); :meth:`CalibratedStream.messages` turns the pipeline's result into the
pose and check (for ``~/estimate``), the ``~/calibration_check`` and the pose messages: for a
stereo rig ``~/relative_transform`` and ``~/relative_pose`` (camera b in camera a's optical
frame); for one moving camera ``~/angular_velocity`` and ``~/translation_direction`` (no
transform: its parent would be its child).
"""

from __future__ import annotations

import operator
from dataclasses import dataclass
from typing import Any

from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import (
    PoseWithCovarianceStamped,
    TransformStamped,
    TwistWithCovarianceStamped,
    Vector3Stamped,
)
from std_msgs.msg import Header

from sepfm_ros.geometry.calibrated.calibration_check import CalibrationMonitor, MonitorConfig
from sepfm_ros.geometry.calibrated.camera import CalibrationError, CameraModel
from sepfm_ros.geometry.calibrated.correction import CorrectionConfig
from sepfm_ros.pipeline.calibration import CalibratedOutputs, StreamCalibration
from sepfm_ros.pipeline.pipeline import PipelineResult
from sepfm_ros.ros.msgs.calibration import (
    angular_velocity_message,
    calibration_error_status,
    calibration_status,
    camera_model_from_info,
    relative_pose_message,
    relative_transform,
    translation_direction_message,
)


@dataclass
class CamerasUpdate:
    """What :meth:`CalibratedStream.cameras` found.

    Attributes:
        cameras: models of images a and b, or None (estimate in image pixels).
        changed: the calibration in use changed with this pair (new or different camera_info).
        error: the ERROR calibration status when the camera_info is unusable (new this pair).
        reason: why, for the log.
    """

    cameras: tuple[CameraModel, CameraModel] | None
    changed: bool = False
    error: DiagnosticStatus | None = None
    reason: str = ""


@dataclass
class CalibratedMessages:
    """One pair's calibrated outputs as messages, and the pose and check they say."""

    outputs: CalibratedOutputs | None = None
    transform: TransformStamped | None = None
    status: DiagnosticStatus | None = None
    relative_pose: PoseWithCovarianceStamped | None = None
    angular_velocity: TwistWithCovarianceStamped | None = None
    translation_direction: Vector3Stamped | None = None


class CalibratedStream:
    """A stream's calibration from its camera_info messages (not thread-safe: one caller).

    Args:
        stereo: two cameras of a rig (else one camera over time).
        rectified: the images are rectified.
        monitor: the calibration check's parameters.
        correction: the stereo correction's parameters (defaults when None).
        node_fqn: the node's fully qualified name, for the ``<node FQN>: calibration`` status's
            name; hardware_id: its hardware id.
    """

    def __init__(
        self,
        stereo: bool,
        rectified: bool,
        monitor: MonitorConfig | None,
        node_fqn: str,
        hardware_id: str = "",
        correction: CorrectionConfig | None = None,
    ) -> None:
        self.calibration = StreamCalibration(stereo, rectified, monitor, correction)
        self.node_fqn = node_fqn
        self.hardware_id = hardware_id
        self._infos: list[Any] | None = None

    def configure_monitor(
        self, config: MonitorConfig, correction: CorrectionConfig | None = None
    ) -> None:
        self.calibration.monitor = CalibrationMonitor(config)
        if correction is not None:
            self.calibration.configure_correction(correction)

    def cameras(self, infos: list[Any] | None, sizes: list[tuple[int, int]]) -> CamerasUpdate:
        """The camera models for a pair whose images have ``sizes`` (width, height).

        Args:
            infos: the latest CameraInfo of each camera (one in motion mode), or None.
        """
        if infos is None:
            return CamerasUpdate(None)
        if not self.calibration.stereo:
            infos = [infos[0], infos[0]]
        if self._infos is not None and all(map(operator.is_, infos, self._infos)):
            return CamerasUpdate(self.calibration.cameras)  # the same messages as before
        self._infos = infos
        try:
            models = [camera_model_from_info(i, s) for i, s in zip(infos, sizes, strict=True)]
            changed = self.calibration.update(*models)
        except CalibrationError as err:
            self.calibration.clear()
            status = calibration_error_status(err, self.node_fqn, self.hardware_id)
            return CamerasUpdate(None, True, status, str(err))
        return CamerasUpdate(self.calibration.cameras, changed)

    def frames(self, default_a: str, default_b: str) -> tuple[str, str]:
        """Optical frame ids of cameras a and b (the camera_info's, else the images')."""
        infos = self._infos or [None, None]
        ids = [(i.header.frame_id if i is not None else "") for i in infos]
        return ids[0] or default_a, ids[1] or default_b

    def messages(
        self,
        result: PipelineResult,
        threshold_px: float,
        header: Header,
        frames: tuple[str, str],
        dt_s: float = 0.0,
    ) -> CalibratedMessages:
        """Pose messages and calibration status of a result estimated with the cameras of
        :meth:`cameras` (stamped with the pair's ``header``; ``dt_s``: seconds from image a's
        stamp to image b's, for a moving camera's angular velocity)."""
        outputs = self.calibration.outputs(result, threshold_px)
        out = CalibratedMessages(outputs)
        pose = outputs.pose
        if pose is not None and pose.ok and self.calibration.stereo:
            out.transform = relative_transform(pose, header, *frames)
            out.relative_pose = relative_pose_message(pose, header, frames[0])
        elif pose is not None and pose.ok:
            out.angular_velocity = angular_velocity_message(pose, header, frames[0], dt_s)
            out.translation_direction = translation_direction_message(pose, header, frames[0])
        if outputs.status is not None:
            out.status = calibration_status(outputs.status, self.node_fqn, self.hardware_id)
        return out
