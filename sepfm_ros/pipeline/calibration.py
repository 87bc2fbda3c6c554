"""Calibrated estimation of a stream: the cameras the estimator undistorts with, the relative pose
from each F, and for a calibrated stereo rig the live calibration check. No ROS; shared by the
node and offline processing.

:class:`StreamCalibration` holds the latest camera models of the stream (from ``camera_info``):

- :attr:`StreamCalibration.cameras` are the models the pipeline undistorts the matched points
  with (:meth:`~sepfm_ros.pipeline.pipeline.Pipeline.estimate`): the raw models for raw images
  (F in undistorted pixels of K), the rectified models (K = P[:, :3], D = 0) for rectified images;
- :meth:`StreamCalibration.outputs` turns a result into the relative pose of camera b in camera
  a (unit translation in motion mode; metres of the calibrated baseline for a stereo rig) and,
  for a stereo rig whose P matrices give a baseline, the pair's check against the calibration
  and the sliding-window decision (:mod:`sepfm_ros.geometry.calibrated.calibration_check`);
- while that decision is WARN or ERROR, the corrected rig from the matches of the last
  ``correction_window`` usable pairs (:mod:`sepfm_ros.geometry.calibrated.correction`, a window
  of its own, cleared when the calibration changes), and :meth:`StreamCalibration.corrected_models`
  gives the camera_info models a driver should load for it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sepfm_ros.geometry.calibrated.calibration_check import (
    ERROR,
    WARN,
    CalibrationMonitor,
    CalibrationStatus,
    MonitorConfig,
    PairCheck,
    StereoCalibration,
    check_pair,
)
from sepfm_ros.geometry.calibrated.camera import CalibrationError, CameraModel
from sepfm_ros.geometry.calibrated.correction import (
    CorrectionConfig,
    CorrectionResult,
    CorrectionWindow,
    estimate_correction,
)
from sepfm_ros.geometry.calibrated.pose import RelativePose, relative_pose
from sepfm_ros.geometry.calibrated.stereo_rectify import corrected_models
from sepfm_ros.pipeline.pipeline import PipelineResult


@dataclass(frozen=True)
class CalibratedOutputs:
    """What calibration adds to one pair's result.

    Attributes:
        pose: relative pose (b in a), None without F; ``pose.status`` says why it is unusable.
        scaled: the pose's translation is in metres (stereo rig), not unit length.
        check: the stereo pair's disagreement with the calibration, None without a rig.
        status: the calibration check's decision after this pair, None without a rig.
        correction: the corrected rig after this pair (``correction.correction`` None with the
            reason when there is none: not needed, too few pairs, degenerate), None without a
            rig.
    """

    pose: RelativePose | None
    scaled: bool
    check: PairCheck | None
    status: CalibrationStatus | None
    correction: CorrectionResult | None = None


# Two camera_info calibrations are the same when each of K, D, R and P agrees entry by entry to
# this fraction of its largest entry (at least 1): for K and P a millionth of the focal length,
# under 0.001 px for any camera. Drivers and tools recompute the calibration for every message,
# some in single precision (relative rounding 6e-8), and a sequence's per-frame calibration
# files carry a few significant digits less (KITTI's differ by 1e-7 of the focal length).
SAME_CALIBRATION_TOL = 1e-6


def _close(a: np.ndarray, b: np.ndarray) -> bool:
    """Arrays of one shape equal to :data:`SAME_CALIBRATION_TOL` of ``b``'s largest entry."""
    if a.shape != b.shape:
        return False
    scale = max(1.0, float(np.max(np.abs(b), initial=0.0)))
    return bool(np.all(np.abs(a - b) <= SAME_CALIBRATION_TOL * scale))


def _same(a: CameraModel, b: CameraModel) -> bool:
    """The same calibration, to rounding (:data:`SAME_CALIBRATION_TOL`)."""
    return (
        a.size == b.size
        and a.distortion_model == b.distortion_model
        and all(_close(getattr(a, f), getattr(b, f)) for f in ("K", "D", "R", "P"))
    )


class StreamCalibration:
    """The calibration of one stream (a stereo rig, or one moving camera).

    Args:
        stereo: the two images of a pair come from two cameras of a rig (else one camera over
            time: a and b share the model).
        rectified: the images are rectified (``image_rect``), so their pixels are P's.
        monitor: the calibration check's sliding-window parameters.
        correction: the correction's parameters (its window of pairs among them).
    """

    def __init__(
        self,
        stereo: bool,
        rectified: bool,
        monitor: MonitorConfig | None = None,
        correction: CorrectionConfig | None = None,
    ) -> None:
        self.stereo = stereo
        self.rectified = rectified
        self.monitor = CalibrationMonitor(monitor)
        self.correction_config = correction or CorrectionConfig()
        self.correction_window = CorrectionWindow(
            self.correction_config.window, self.correction_config.min_matches
        )
        self.correction: CorrectionResult | None = None
        self._models: tuple[CameraModel, CameraModel] | None = None
        self.cameras: tuple[CameraModel, CameraModel] | None = None
        self.rig: StereoCalibration | None = None
        self.rig_problem: str | None = None  # why a stereo pair has no calibration check

    def update(self, model_a: CameraModel, model_b: CameraModel) -> bool:
        """Use these camera models (of image a and image b) from now on; True when they
        changed (the check's window then starts afresh).

        Raises:
            CalibrationError: the models cannot describe these images (e.g. rectified images
                with a P without a pinhole part).
        """
        if self._models is not None and all(map(_same, self._models, (model_a, model_b))):
            return False
        if self.rectified:
            cameras = (model_a.rectified(), model_b.rectified())
        else:
            cameras = (model_a, model_b)
        rig, problem = None, None
        if self.stereo:
            try:
                rig = StereoCalibration.from_models(model_a, model_b, self.rectified)
            except (CalibrationError, ValueError, np.linalg.LinAlgError) as err:
                problem = f"no calibrated stereo geometry in the camera_info P matrices: {err}"
            if rig is not None and not rig.baseline > 0.0:
                rig, problem = None, "the camera_info P matrices give no stereo baseline"
        self._models = (model_a, model_b)
        self.cameras = cameras
        self.rig, self.rig_problem = rig, problem
        self.monitor.reset()
        self._reset_correction()
        return True

    def clear(self) -> None:
        """Forget the models (calibration became unusable): estimate without them."""
        self._models = self.cameras = self.rig = None
        self.rig_problem = None
        self.monitor.reset()
        self._reset_correction()

    def configure_correction(self, config: CorrectionConfig) -> None:
        """New correction parameters; the window keeps its newest pairs that still fit."""
        old = self.correction_window.pairs
        self.correction_config = config
        self.correction_window = CorrectionWindow(config.window, config.min_matches)
        for pair in old:
            self.correction_window.add(pair.pts_a, pair.pts_b, pair.first)

    def _reset_correction(self) -> None:
        self.correction_window.clear()
        self.correction = None

    def corrected_models(self) -> tuple[CameraModel, CameraModel] | None:
        """The camera_info models (a, b) of the current correction: the models given to
        :meth:`update` with R and P of the corrected rectification
        (:func:`~sepfm_ros.geometry.calibrated.stereo_rectify.corrected_models`); None without
        a correction."""
        if self._models is None or self.correction is None or self.correction.correction is None:
            return None
        fix = self.correction.correction
        return corrected_models(*self._models, fix.R, fix.t, self.rectified)

    def outputs(self, result: PipelineResult, threshold_px: float) -> CalibratedOutputs:
        """Pose and calibration check of one result estimated with :attr:`cameras`.

        Args:
            result: the pipeline's result (``coordinates == "undistorted"``).
            threshold_px: the estimator's inlier threshold (soft-L1 scale of the refinements).
        """
        if self.cameras is None or result.coordinates != "undistorted":
            return CalibratedOutputs(None, False, None, None)
        est = result.estimate
        pts_a, pts_b = result.matches.pts_a, result.matches.pts_b
        pose = None
        if est.F is not None:
            K_a, K_b = self.cameras[0].K, self.cameras[1].K
            pose = relative_pose(est.F, pts_a, pts_b, K_a, K_b, est.inliers, scale_px=threshold_px)
        scaled = False
        if self.rig is not None and pose is not None and pose.ok:
            scaled, pose = True, pose.scaled(self.rig.baseline)
        if self.rig is None:
            return CalibratedOutputs(pose, scaled, None, None)
        inliers = est.inliers if est.F is not None else np.zeros(len(pts_a), bool)
        check = check_pair(
            self.rig,
            pts_a,
            pts_b,
            inliers,
            min_inliers=self.monitor.config.min_inliers,
            scale_px=threshold_px,
        )
        status = self.monitor.update(check)
        if check.usable and check.fit is not None:
            # the correction fits the sub-pixel points of b when the pipeline tracked them
            # (its failed tracks, NaN, are left out); the check keeps the detected ones
            self.correction_window.add(
                pts_a, pts_b if result.refined_b is None else result.refined_b, check.fit
            )
        self.correction = self._correction(status)
        return CalibratedOutputs(pose, scaled, check, status, self.correction)

    def _correction(self, status: CalibrationStatus) -> CorrectionResult:
        """The correction after this pair's decision: estimated at WARN or ERROR only."""
        if self.rig is None or status.level not in (WARN, ERROR):
            return CorrectionResult(
                None, f"no correction needed: calibration check {status.level_name}"
            )
        return estimate_correction(self.rig, self.correction_window, self.correction_config)
