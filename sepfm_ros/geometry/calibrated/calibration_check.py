"""Stereo calibration check: how far a rig's current matches are from its calibration. No ROS.

Per stereo pair (:func:`check_pair`), the inlier matches of the estimated F are measured against
the calibrated geometry (:class:`StereoCalibration`):

- epipolar error under the calibrated F (median and 90th percentile of the symmetric epipolar
  distance, px); on rectified images this is the vertical disparity |v_a - v_b|;
- the rotation between the calibrated relative pose and the rotation that best explains the
  matches with the calibrated baseline direction kept (a 3-dof Sampson fit started at the
  calibrated rotation) on the inliers plus the matches within ``band_px`` of the calibrated F
  (the estimated F's 1 px cut drops exactly the matches that show a decalibration when that F
  absorbs it). Keeping the baseline direction matters: a free stereo pose trades a yaw against
  a forward translation (about a degree on KITTI). Even so, the rotation about the axis normal
  to the baseline and the optical axis (yaw, for a horizontal rig) barely moves the epipolar
  lines: it shows as a disparity bias, not an epipolar error, so the decision uses the
  rotation's other two components (``rotation_error_deg``) and reports all three.

:class:`CalibrationMonitor` decides OK / WARN / ERROR over a sliding window of pairs (medians
over the window, so one bad pair does not alarm). Levels are ``diagnostic_msgs/DiagnosticStatus``
levels (OK 0, WARN 1, ERROR 2, STALE 3 while the window has too few usable pairs).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from sepfm_ros.geometry.calibrated.camera import CameraModel
from sepfm_ros.geometry.calibrated.monitor import (  # the decision over a window of pairs
    ERROR,
    LEVEL_NAMES,
    OK,
    STALE,
    WARN,
    CalibrationMonitor,
    CalibrationStatus,
    MonitorConfig,
)
from sepfm_ros.geometry.calibrated.pose import (
    refine_pose,
    stereo_baseline,
    stereo_fundamental,
    stereo_pose,
)
from sepfm_ros.geometry.epipolar import symmetric_epipolar_distance

__all__ = [
    "ERROR",
    "LEVEL_NAMES",
    "OK",
    "STALE",
    "WARN",
    "CalibrationMonitor",
    "CalibrationStatus",
    "MonitorConfig",
    "PairCheck",
    "StereoCalibration",
    "check_pair",
    "weak_rotation_axis",
]


@dataclass(frozen=True)
class StereoCalibration:
    """A stereo rig's calibrated geometry in the pixels the estimator sees.

    Attributes:
        model_a, model_b: the camera models of the images as received (raw: undistort with
            them; rectified: :meth:`CameraModel.rectified` models, D = 0).
        F: (3, 3) calibrated F in those pixels (x_b^T F x_a = 0).
        R, t: calibrated relative pose (``X_b = R X_a + t``, t in metres).
        baseline: |t| (metres).
        rectified: True when the images are rectified (``image_rect``).
    """

    model_a: CameraModel
    model_b: CameraModel
    F: np.ndarray
    R: np.ndarray
    t: np.ndarray
    baseline: float
    rectified: bool

    @classmethod
    def from_models(
        cls, info_a: CameraModel, info_b: CameraModel, rectified: bool = False
    ) -> StereoCalibration:
        """The rig from the left (a) and right (b) camera_info models.

        Args:
            info_a, info_b: models built from the two ``CameraInfo`` messages.
            rectified: the images are rectified (pixels of P); otherwise raw (pixels of K, D).
        Raises:
            CalibrationError: P has no pinhole part; ValueError: no baseline in the P matrices.
        """
        model_a = info_a.rectified() if rectified else info_a
        model_b = info_b.rectified() if rectified else info_b
        R, t = stereo_pose(model_a, model_b)
        return cls(
            model_a,
            model_b,
            stereo_fundamental(model_a, model_b),
            R,
            t,
            stereo_baseline(info_a, info_b),
            rectified,
        )


@dataclass(frozen=True)
class PairCheck:
    """One pair's disagreement with the calibration.

    Attributes:
        n_inliers: inlier matches measured.
        epipolar_median_px, epipolar_p90_px: symmetric epipolar distance of the inliers under
            the calibrated F (px); NaN when there are too few inliers.
            rotation_error_deg: the observable part of the rotation between the calibrated rotation
            and the matches' rotation: its angle without the component about the weak axis
            (normal to the baseline and the optical axis; yaw for a horizontal rig).
        rotation_axes_deg: (3,) that rotation as a rotation vector in b's optical axes (x right,
            y down, z forward), degrees: pitch (x), yaw (y), roll (z).
        usable: at least ``min_inliers`` inliers were measured.
        fit: (N,) bool mask of the matches the rotation was fitted on (the inliers plus the
            band), None when the pair is unusable.
    """

    n_inliers: int
    epipolar_median_px: float
    epipolar_p90_px: float
    rotation_error_deg: float
    rotation_axes_deg: np.ndarray
    usable: bool
    fit: np.ndarray | None = field(default=None, compare=False, repr=False)


def check_pair(
    calib: StereoCalibration,
    pts_a: np.ndarray,
    pts_b: np.ndarray,
    inliers: np.ndarray,
    min_inliers: int = 30,
    scale_px: float = 1.0,
    band_px: float = 3.0,
) -> PairCheck:
    """Measure one stereo pair's inlier matches against the calibration.

    Args:
        calib: the rig.
        pts_a, pts_b: (N, 2) matches in the estimator's pixels (undistorted pixels of K for raw
            images, i.e. after :func:`~sepfm_ros.geometry.calibrated.camera.undistort_points`).
        inliers: (N,) bool inlier mask of the estimated F.
        min_inliers: fewer inliers make the pair unusable (figures NaN).
        scale_px: soft-L1 scale (px) of the rotation fit, e.g. the estimator's threshold.
        band_px: matches within this calibrated epipolar distance (px) join the inliers in the
            rotation fit.
    """
    pts_a = np.asarray(pts_a, dtype=np.float64).reshape(-1, 2)
    pts_b = np.asarray(pts_b, dtype=np.float64).reshape(-1, 2)
    mask = np.asarray(inliers, dtype=bool).reshape(-1)
    if not len(pts_a) == len(pts_b) == len(mask):
        raise ValueError(
            f"pts_a, pts_b and inliers differ in length: {len(pts_a)}, {len(pts_b)}, {len(mask)}"
        )
    n = int(np.count_nonzero(mask))
    if n < max(int(min_inliers), 5):
        return PairCheck(n, np.nan, np.nan, np.nan, np.full(3, np.nan), False)
    d_all = symmetric_epipolar_distance(calib.F, pts_a, pts_b)
    d = d_all[mask]
    fit = mask | (d_all < float(band_px))
    K_a, K_b = calib.model_a.K, calib.model_b.K
    R, _ = refine_pose(
        calib.R, calib.t, pts_a[fit], pts_b[fit], K_a, K_b, scale_px, fix_translation=True
    )
    rotvec = Rotation.from_matrix(R @ calib.R.T).as_rotvec()
    weak = weak_rotation_axis(calib)
    observable = rotvec - (rotvec @ weak) * weak
    return PairCheck(
        n,
        float(np.median(d)),
        float(np.percentile(d, 90)),
        float(np.degrees(np.linalg.norm(observable))),
        np.degrees(rotvec),
        True,
        fit,
    )


def weak_rotation_axis(calib: StereoCalibration) -> np.ndarray:
    """(3,) unit axis (b's frame) whose rotations the epipolar geometry barely sees.

    The normal to the baseline and b's optical axis: y (yaw) for a horizontal rig.
    """
    axis = np.cross(calib.t, [0.0, 0.0, 1.0])
    n = np.linalg.norm(axis)
    return axis / n if n > 1e-12 else np.array([0.0, 1.0, 0.0])
