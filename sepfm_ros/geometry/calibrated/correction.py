"""Corrected stereo extrinsics from a window of pairs: the rotation of camera b that the matches
show. No ROS.

Model. A knock, heat or a loose mount turns camera b about its own centre by a small rotation
``dR``: its centre stays where it was in the rig (camera a's frame), so the relative pose becomes
``R' = dR R``, ``t' = dR t`` (``X_b = R X_a + t``). Its essential matrix is ``dR E``: the
correction acts on b's image alone, as the homography ``K_b dR K_b^-1``. (Keeping ``t`` fixed in
b's frame instead, as the per-pair check of
:func:`~sepfm_ros.geometry.calibrated.calibration_check.check_pair` does, moves b's centre
sideways by ``|t| * angle``: at finite depth this shifts the rows by ``angle * disparity`` and a
fit of a roll reads about 15 % low on KITTI.)

Estimate (:func:`estimate_correction`):

1. each pair of the window is fitted alone (3-dof Sampson fit, soft-L1 beyond
   :attr:`CorrectionConfig.scale_px`); cached per pair;
2. pairs whose observable rotation is far from the window's median (more than
   :attr:`CorrectionConfig.outlier_sigma` robust deviations, MAD) are dropped as bad pairs;
3. the kept pairs' matches are fitted together (3 dof); the 95 % interval per axis is Student's
   t over the kept pairs' own fits: ``t_0.975(n-1) * std / sqrt(n)`` (matches of one pair are
   correlated, pairs much less);
4. yaw (the rotation about the axis normal to the baseline and b's optical axis) moves points
   along the epipolar lines: a disparity bias, not an epipolar error. It is kept at the
   calibrated value (the fit repeated with it fixed) unless its interval is narrower than
   :attr:`CorrectionConfig.yaw_max_interval_deg` and excludes zero.

No correction (``CorrectionResult.correction is None``, with the reason) from fewer than
:attr:`CorrectionConfig.min_pairs` pairs, from matches that cover too little of the image, from
an interval wider than :attr:`CorrectionConfig.max_interval_deg` (the rotation is not determined),
or when the observable rotation is within its interval of the calibration (nothing to correct).

Axes: b's optical frame (x right, y down, z forward): pitch (x), yaw (y), roll (z), degrees.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation
from scipy.stats import t as student_t

from sepfm_ros.geometry.calibrated.calibration_check import (
    StereoCalibration,
    weak_rotation_axis,
)
from sepfm_ros.geometry.epipolar import homogeneous


@dataclass(frozen=True)
class CorrectionConfig:
    """Parameters of :func:`estimate_correction` (node parameter ``correction_window``).

    Attributes:
        window: usable pairs whose matches are kept (>= 1).
        min_pairs: pairs needed for a correction (2 <= min_pairs <= window).
        min_matches: matches a pair needs to enter the window.
        scale_px: soft-L1 scale of the Sampson residuals (px).
        outlier_sigma: a pair whose own rotation is further than this many robust deviations
            (1.4826 MAD, at least ``outlier_floor_deg``) from the window's median is dropped.
        outlier_floor_deg: the smallest deviation (degrees) used for that test.
        max_interval_deg: no correction when the pitch or roll interval (95 % half-width,
            degrees) is wider: the matches do not determine the rotation.
        yaw_max_interval_deg: yaw is corrected only when its interval is narrower than this
            (degrees) and excludes zero.
        min_coverage: the matches must spread over at least this share of the image width and
            height (robust extent, 5th to 95th percentile), else no correction.
    """

    window: int = 40
    min_pairs: int = 10
    min_matches: int = 20
    scale_px: float = 1.0
    outlier_sigma: float = 4.0
    outlier_floor_deg: float = 0.02
    max_interval_deg: float = 0.1
    yaw_max_interval_deg: float = 0.05
    min_coverage: float = 0.25

    def __post_init__(self) -> None:
        errors = []
        if not int(self.window) >= 1:
            errors.append(f"window must be >= 1, got {self.window}")
        if not 2 <= int(self.min_pairs) <= max(int(self.window), 2):
            errors.append(f"min_pairs must be in [2, window], got {self.min_pairs}")
        if int(self.min_matches) < 5:
            errors.append(f"min_matches must be >= 5, got {self.min_matches}")
        for name in ("scale_px", "outlier_sigma", "max_interval_deg", "yaw_max_interval_deg"):
            if not float(getattr(self, name)) > 0:
                errors.append(f"{name} must be > 0, got {getattr(self, name)}")
        if not float(self.outlier_floor_deg) >= 0:
            errors.append(f"outlier_floor_deg must be >= 0, got {self.outlier_floor_deg}")
        if not 0 <= float(self.min_coverage) < 1:
            errors.append(f"min_coverage must be in [0, 1), got {self.min_coverage}")
        if errors:
            raise ValueError("invalid correction config: " + "; ".join(errors))


@dataclass
class _Pair:
    pts_a: np.ndarray
    pts_b: np.ndarray
    fits: dict[int, np.ndarray] = field(default_factory=dict)  # id(calib) -> rotvec (3,)


class CorrectionWindow:
    """The matches of the last ``window`` usable pairs, for the rotation fit.

    Matches are in the estimator's pixels (undistorted pixels of K for raw images), the ones
    the calibration check fits: the estimated F's inliers plus the band around the calibrated F.
    """

    def __init__(self, window: int = 40, min_matches: int = 20) -> None:
        if int(window) < 1:
            raise ValueError(f"correction window must be >= 1, got {window}")
        self.min_matches = int(min_matches)
        self._pairs: deque[_Pair] = deque(maxlen=int(window))

    def add(self, pts_a: np.ndarray, pts_b: np.ndarray) -> bool:
        """Keep one pair's (N, 2) matches; False (not kept) with fewer than ``min_matches``."""
        a = np.asarray(pts_a, dtype=np.float64).reshape(-1, 2)
        b = np.asarray(pts_b, dtype=np.float64).reshape(-1, 2)
        if len(a) != len(b):
            raise ValueError(f"pts_a and pts_b differ in length: {len(a)}, {len(b)}")
        good = np.all(np.isfinite(a), axis=1) & np.all(np.isfinite(b), axis=1)
        if np.count_nonzero(good) < self.min_matches:
            return False
        self._pairs.append(_Pair(a[good].copy(), b[good].copy()))
        return True

    def clear(self) -> None:
        """Forget every pair (e.g. the calibration changed)."""
        self._pairs.clear()

    def __len__(self) -> int:
        return len(self._pairs)

    @property
    def pairs(self) -> list[_Pair]:
        return list(self._pairs)


@dataclass(frozen=True)
class RigCorrection:
    """A corrected rig.

    Attributes:
        R: (3, 3) corrected rotation of camera b relative to a (``X_b = R X_a + t``).
        t: (3,) the corrected translation: the calibrated baseline with b's centre kept in
            place (``dR t``; its length is the calibrated baseline, metres).
        axes_deg: (3,) the correction ``R @ calib.R.T`` as a rotation vector in b's optical
            axes, degrees: pitch (x), yaw (y), roll (z).
        interval_deg: (3,) 95 % half-widths of those, degrees (yaw's is reported even when yaw
            is not corrected).
        yaw_determined: the data determines yaw and it is corrected (else it is left at the
            calibrated value: ``axes_deg`` has no component about the weak axis).
        n_pairs: pairs used (after dropping bad ones); n_matches: their matches.
        yaw_estimate_deg: the yaw the free fit gave (degrees), applied or not.
    """

    R: np.ndarray
    t: np.ndarray
    axes_deg: np.ndarray
    interval_deg: np.ndarray
    yaw_determined: bool
    n_pairs: int
    n_matches: int
    yaw_estimate_deg: float = float("nan")


@dataclass(frozen=True)
class CorrectionResult:
    """A correction, or why there is none (``reason``: one line for humans)."""

    correction: RigCorrection | None
    reason: str


def correction_residuals(
    omega: np.ndarray,
    E: np.ndarray,
    xa: np.ndarray,
    xb: np.ndarray,
    Ka_inv: np.ndarray,
    Kb_inv: np.ndarray,
) -> np.ndarray:
    """Signed Sampson distances (px) of homogeneous matches (N, 3) under ``exp(omega) E``.

    Args:
        omega: (3,) rotation vector (rad) of camera b about its centre, in b's frame.
        E: (3, 3) calibrated essential matrix ``[t]_x R``.
    """
    F = Kb_inv.T @ Rotation.from_rotvec(omega).as_matrix() @ E @ Ka_inv
    Fx = xa @ F.T
    Ftx = xb @ F
    r = np.einsum("ij,ij->i", xb, Fx)
    den = np.sqrt(Fx[:, 0] ** 2 + Fx[:, 1] ** 2 + Ftx[:, 0] ** 2 + Ftx[:, 1] ** 2)
    return np.asarray(r / np.maximum(den, 1e-12))


def fit_rotation(
    calib: StereoCalibration,
    pts_a: np.ndarray,
    pts_b: np.ndarray,
    scale_px: float = 1.0,
    fixed_axis: np.ndarray | None = None,
    start: np.ndarray | None = None,
) -> np.ndarray:
    """(3,) rotation vector (rad, b's frame) of camera b about its centre that best explains the
    (N, 2) matches (Sampson, soft-L1 beyond ``scale_px``); with ``fixed_axis`` (3,) unit, no
    component about it (2 dof)."""
    E = _essential(calib)
    xa, xb = homogeneous(pts_a), homogeneous(pts_b)
    Ka_inv, Kb_inv = np.linalg.inv(calib.model_a.K), np.linalg.inv(calib.model_b.K)
    if fixed_axis is None:
        basis = np.eye(3)
    else:
        basis = np.linalg.svd(np.asarray(fixed_axis, dtype=np.float64)[None])[2][1:].T  # (3, 2)
    p0 = np.zeros(basis.shape[1]) if start is None else basis.T @ np.asarray(start)

    def fun(p: np.ndarray) -> np.ndarray:
        return correction_residuals(basis @ p, E, xa, xb, Ka_inv, Kb_inv)

    sol = least_squares(fun, p0, loss="soft_l1", f_scale=float(scale_px), x_scale=1e-3)
    return np.asarray(basis @ sol.x)


def _essential(calib: StereoCalibration) -> np.ndarray:
    t = np.asarray(calib.t, dtype=np.float64)
    t = t / np.linalg.norm(t)
    return np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]]) @ calib.R


def _pair_fit(calib: StereoCalibration, pair: _Pair, scale_px: float) -> np.ndarray:
    key = id(calib)
    if key not in pair.fits:
        pair.fits = {key: fit_rotation(calib, pair.pts_a, pair.pts_b, scale_px)}
    return pair.fits[key]


def _coverage(calib: StereoCalibration, pts_b: np.ndarray) -> float:
    """Smaller of the matches' robust extents in b's image (5-95th percentile) over its size."""
    lo, hi = np.percentile(pts_b, [5, 95], axis=0)
    w, h = calib.model_b.size
    return float(min((hi[0] - lo[0]) / w, (hi[1] - lo[1]) / h))


def _observable(v: np.ndarray, weak: np.ndarray) -> np.ndarray:
    return np.asarray(v - np.outer(v @ weak, weak) if v.ndim == 2 else v - (v @ weak) * weak)


def estimate_correction(
    calib: StereoCalibration, window: CorrectionWindow, config: CorrectionConfig
) -> CorrectionResult:
    """The rotation of camera b (about its centre) that the window's matches show, or why none.

    Args:
        calib: the calibrated rig (intrinsics, R, t in the estimator's pixels).
        window: the matches of the last usable pairs.
        config: thresholds.
    """
    pairs = window.pairs
    if len(pairs) < config.min_pairs:
        return CorrectionResult(
            None, f"too few pairs for a correction: {len(pairs)} of {config.min_pairs}"
        )
    weak = weak_rotation_axis(calib)
    fits = np.array([_pair_fit(calib, p, config.scale_px) for p in pairs])  # (n, 3) rad
    obs = _observable(fits, weak)
    med = np.median(obs, axis=0)
    dev = np.linalg.norm(obs - med, axis=1)
    mad = 1.4826 * float(np.median(dev))
    limit = config.outlier_sigma * max(mad, np.radians(config.outlier_floor_deg))
    keep = dev <= limit
    n = int(np.count_nonzero(keep))
    if n < config.min_pairs:
        return CorrectionResult(
            None,
            f"too few consistent pairs for a correction: {n} of {len(pairs)} agree "
            f"(need {config.min_pairs})",
        )
    kept = [p for p, k in zip(pairs, keep, strict=True) if k]
    pa = np.concatenate([p.pts_a for p in kept])
    pb = np.concatenate([p.pts_b for p in kept])
    coverage = _coverage(calib, pb)
    if coverage < config.min_coverage:
        return CorrectionResult(
            None,
            f"degenerate window: the matches span {coverage:.0%} of the image "
            f"(need {config.min_coverage:.0%}); no texture over most of it",
        )
    quantile = float(student_t.ppf(0.975, n - 1))
    half = np.degrees(quantile * fits[keep].std(axis=0, ddof=1) / np.sqrt(n))
    weak_index = int(np.argmax(np.abs(weak)))
    strong = [i for i in range(3) if i != weak_index]
    if np.any(half[strong] > config.max_interval_deg):
        return CorrectionResult(
            None,
            "degenerate window: the matches do not determine the rotation (95 % interval "
            f"{np.max(half[strong]):.3f} deg > {config.max_interval_deg} deg: a plane, no "
            "parallax or too little texture?)",
        )
    free = fit_rotation(calib, pa, pb, config.scale_px, start=np.median(fits[keep], axis=0))
    yaw_free = float(np.degrees(free @ weak))
    yaw_half = float(half[weak_index])
    yaw_determined = yaw_half <= config.yaw_max_interval_deg and abs(yaw_free) > yaw_half
    omega = free
    if not yaw_determined:
        omega = fit_rotation(calib, pa, pb, config.scale_px, fixed_axis=weak, start=free)
    axes = np.degrees(omega)
    significant = np.abs(axes[strong]) > half[strong]
    if not np.any(significant) and not yaw_determined:
        return CorrectionResult(
            None,
            "no correction needed: the matches agree with the calibration within their "
            f"interval (pitch {axes[0]:+.3f} +- {half[0]:.3f}, roll {axes[2]:+.3f} +- "
            f"{half[2]:.3f} deg)",
        )
    dR = Rotation.from_rotvec(omega).as_matrix()
    correction = RigCorrection(
        dR @ calib.R,
        dR @ np.asarray(calib.t, dtype=np.float64),
        axes,
        half,
        yaw_determined,
        n,
        len(pa),
        yaw_free,
    )
    yaw_text = "corrected" if yaw_determined else "kept"
    return CorrectionResult(
        correction,
        f"corrected from {n} pairs ({len(pa)} matches, {len(pairs) - n} dropped): pitch "
        f"{axes[0]:+.3f} +- {half[0]:.3f}, roll {axes[2]:+.3f} +- {half[2]:.3f} deg, yaw "
        f"{yaw_free:+.3f} +- {yaw_half:.3f} deg {yaw_text}",
    )
