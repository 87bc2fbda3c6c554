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

from collections import deque
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from sepfm_ros.geometry.calibrated.camera import CameraModel
from sepfm_ros.geometry.calibrated.pose import (
    refine_pose,
    stereo_baseline,
    stereo_fundamental,
    stereo_pose,
)
from sepfm_ros.geometry.epipolar import symmetric_epipolar_distance

OK, WARN, ERROR, STALE = 0, 1, 2, 3
LEVEL_NAMES = {OK: "OK", WARN: "WARN", ERROR: "ERROR", STALE: "STALE"}


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


@dataclass(frozen=True)
class MonitorConfig:
    """Parameters of :class:`CalibrationMonitor` (node parameters ``calibration_check.*``).

    Attributes:
        window: pairs in the sliding window (>= 1).
        min_pairs: usable pairs needed in the window before a decision (else STALE).
        min_inliers: inliers a pair needs to be usable.
        warn_epipolar_px, error_epipolar_px: thresholds on the window median of the pairs'
            median epipolar error (px).
        warn_rotation_deg, error_rotation_deg: thresholds on the window median of the pairs'
            rotation error (degrees).
    """

    window: int = 10
    min_pairs: int = 5
    min_inliers: int = 30
    warn_epipolar_px: float = 1.0
    error_epipolar_px: float = 3.0
    warn_rotation_deg: float = 0.07
    error_rotation_deg: float = 0.5

    def __post_init__(self) -> None:
        errors = []
        if not int(self.window) >= 1:
            errors.append(f"window must be >= 1, got {self.window}")
        if not 1 <= int(self.min_pairs) <= int(self.window):
            errors.append(f"min_pairs must be in [1, window], got {self.min_pairs}")
        if int(self.min_inliers) < 5:
            errors.append(f"min_inliers must be >= 5, got {self.min_inliers}")
        for warn, err, unit in (
            (self.warn_epipolar_px, self.error_epipolar_px, "epipolar_px"),
            (self.warn_rotation_deg, self.error_rotation_deg, "rotation_deg"),
        ):
            if not 0 < float(warn) <= float(err):
                errors.append(f"need 0 < warn_{unit} <= error_{unit}, got {warn}, {err}")
        if errors:
            raise ValueError("invalid calibration check config: " + "; ".join(errors))


@dataclass(frozen=True)
class CalibrationStatus:
    """The monitor's decision after a pair.

    Attributes:
        level: OK, WARN, ERROR or STALE (diagnostic_msgs levels 0..3).
        message: one line for humans.
        values: figures (str -> float/int) for the diagnostic's key/values.
    """

    level: int
    message: str
    values: dict[str, float | int] = field(default_factory=dict)

    @property
    def level_name(self) -> str:
        return LEVEL_NAMES[self.level]


class CalibrationMonitor:
    """Sliding-window OK / WARN / ERROR decision over :class:`PairCheck` results."""

    def __init__(self, config: MonitorConfig | None = None) -> None:
        self.config = config or MonitorConfig()
        self._window: deque[PairCheck] = deque(maxlen=int(self.config.window))

    def reset(self) -> None:
        """Forget the window (e.g. after a new calibration arrived)."""
        self._window.clear()

    def update(self, check: PairCheck) -> CalibrationStatus:
        """Add one pair's check and decide."""
        self._window.append(check)
        return self.status()

    def status(self) -> CalibrationStatus:
        """The decision on the current window."""
        cfg = self.config
        usable = [c for c in self._window if c.usable]
        values: dict[str, float | int] = {
            "pairs_in_window": len(self._window),
            "usable_pairs": len(usable),
        }
        last = self._window[-1] if self._window else None
        if last is not None:
            values.update(
                last_inliers=last.n_inliers,
                last_epipolar_median_px=last.epipolar_median_px,
                last_epipolar_p90_px=last.epipolar_p90_px,
                last_rotation_error_deg=last.rotation_error_deg,
            )
        if len(usable) < cfg.min_pairs:
            return CalibrationStatus(
                STALE,
                f"calibration not checked: {len(usable)} of {cfg.min_pairs} pairs with at least "
                f"{cfg.min_inliers} inliers in the last {len(self._window)}",
                values,
            )
        epi = float(np.median([c.epipolar_median_px for c in usable]))
        p90 = float(np.median([c.epipolar_p90_px for c in usable]))
        rot = float(np.median([c.rotation_error_deg for c in usable]))
        axes = np.median([c.rotation_axes_deg for c in usable], axis=0)
        values.update(
            epipolar_median_px=epi,
            epipolar_p90_px=p90,
            rotation_error_deg=rot,
            rotation_x_deg=float(axes[0]),
            rotation_y_deg=float(axes[1]),
            rotation_z_deg=float(axes[2]),
        )
        figures = f"epipolar error {epi:.2f} px (p90 {p90:.2f}), rotation {rot:.3f} deg"
        if epi > cfg.error_epipolar_px or rot > cfg.error_rotation_deg:
            return CalibrationStatus(ERROR, f"stereo calibration is off: {figures}", values)
        if epi > cfg.warn_epipolar_px or rot > cfg.warn_rotation_deg:
            return CalibrationStatus(WARN, f"stereo calibration drifting: {figures}", values)
        return CalibrationStatus(OK, f"stereo calibration holds: {figures}", values)
