"""The stereo correction's parameters (:class:`CorrectionConfig`), in a module of their own with
no numerical import, so the node's parameter table can take their defaults at start-up; the
correction itself is :mod:`sepfm_ros.geometry.calibrated.correction`. No ROS."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class CorrectionConfig:
    """Parameters of :func:`estimate_correction` (node parameter ``correction_window``).

    Attributes:
        window: usable pairs whose matches are kept (>= 1).
        min_pairs: pairs needed for a correction (2 <= min_pairs <= window).
        min_matches: matches a pair needs to enter the window.
        scale_px: soft-L1 scale of the Sampson residuals (px). The band already drops wrong
            matches; within it a wider scale is closer to least squares (a 0.2 deg roll knock
            on KITTI reads 0.135 deg at 1 px, 0.163 deg at 3 px).
        outlier_sigma: a pair whose own rotation is further than this many robust deviations
            (1.4826 MAD, at least ``outlier_floor_deg``) from the window's median is dropped.
        outlier_floor_deg: the smallest deviation (degrees) used for that test.
        max_interval_deg: no correction when the pitch or roll interval (95 % half-width,
            degrees) is wider: the matches do not determine the rotation.
        yaw_max_interval_deg: yaw is corrected only when its interval is narrower than this
            (degrees) and excludes zero.
        min_coverage: the matches must spread over at least this share of the image width and
            height (robust extent, 5th to 95th percentile), else no correction.
        band_px: after a first fit, the matches within this Sampson distance (px) of the fitted
            rotation are refitted (twice), so that the matches a large knock moved far from the
            calibrated F count.
        systematic_mrad: a per-ray angle (milliradians) that does not average out over
            matches or pairs (the calibration's own accuracy, the rig model's residual): in b's
            pixels ``s = systematic_mrad * 1e-3 * f_b``, which adds
            ``s * sqrt(diag((J^T J / N)^-1))`` to each interval, in quadrature. An angle, not
            pixels: the floor the benchmark's rigs need scales with their focal length (KITTI,
            f = 719 px, and 343-px synthetic rigs both need about 0.06 mrad: 0.043 and 0.021 px).
        min_correction_deg: no correction unless the observable correction (pitch and roll)
            is at least this (degrees) beyond its 95 % interval (the norm over the two axes of
            ``max(|angle| - half-width, 0)``): below it the rows move by a fraction of a pixel,
            and a rig whose calibration is a few hundredths of a degree off is not rewritten.
    """

    window: int = 40
    min_pairs: int = 10
    min_matches: int = 20
    scale_px: float = 3.0
    outlier_sigma: float = 4.0
    outlier_floor_deg: float = 0.02
    max_interval_deg: float = 0.1
    yaw_max_interval_deg: float = 0.05
    min_coverage: float = 0.25
    band_px: float = 2.0
    systematic_mrad: float = 0.06
    min_correction_deg: float = 0.05

    def __post_init__(self) -> None:
        errors = []
        if not int(self.window) >= 1:
            errors.append(f"window must be >= 1, got {self.window}")
        if not 2 <= int(self.min_pairs) <= max(int(self.window), 2):
            errors.append(f"min_pairs must be in [2, window], got {self.min_pairs}")
        if int(self.min_matches) < 5:
            errors.append(f"min_matches must be >= 5, got {self.min_matches}")
        for name in (
            "scale_px",
            "outlier_sigma",
            "max_interval_deg",
            "yaw_max_interval_deg",
            "band_px",
        ):
            if not float(getattr(self, name)) > 0:
                errors.append(f"{name} must be > 0, got {getattr(self, name)}")
        for name in ("outlier_floor_deg", "systematic_mrad", "min_correction_deg"):
            if not float(getattr(self, name)) >= 0:
                errors.append(f"{name} must be >= 0, got {getattr(self, name)}")
        if not 0 <= float(self.min_coverage) < 1:
            errors.append(f"min_coverage must be in [0, 1), got {self.min_coverage}")
        if errors:
            raise ValueError("invalid correction config: " + "; ".join(errors))
