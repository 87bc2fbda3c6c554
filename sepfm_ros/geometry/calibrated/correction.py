"""Corrected stereo extrinsics from a window of pairs: the rotation of camera b that the matches
show. No ROS.

Model. A knock, heat or a loose mount turns camera b about its own centre by a small rotation
``dR``: its centre stays where it was in the rig (camera a's frame), so the relative pose becomes
``R' = dR R``, ``t' = dR t`` (``X_b = R X_a + t``). Its essential matrix is ``dR E``: the
correction acts on b's image alone, as the homography ``K_b dR K_b^-1``, the warp that
benchmarks inject. (Keeping ``t`` fixed in b's frame instead, as the per-pair check of
:func:`~sepfm_ros.geometry.calibrated.calibration_check.check_pair` does, moves b's centre
sideways by ``|t| * angle``; on KITTI both read the same within 0.005 deg.)

Estimate (:func:`estimate_correction`):

1. each pair of the window is fitted alone (3-dof Sampson fit, soft-L1 beyond
   :attr:`CorrectionConfig.scale_px`), first on the check's matches, then twice on all its
   matches within :attr:`CorrectionConfig.band_px` of its own fit; cached per pair;
2. pairs whose observable rotation is far from the median of the newest
   :attr:`CorrectionConfig.min_pairs` pairs (more than :attr:`CorrectionConfig.outlier_sigma`
   robust deviations, MAD) are dropped as bad pairs, and so are the pairs from before a change
   of the rig;
3. the estimate is the mean of the kept pairs' fits; the 95 % interval per axis is Student's
   t over them, ``t_0.975(n-1) * std / sqrt(n)`` (matches of one pair are correlated, pairs
   much less), with a systematic floor :attr:`CorrectionConfig.systematic_mrad` in quadrature;
4. yaw (the rotation about the axis normal to the baseline and b's optical axis) moves points
   along the epipolar lines: a disparity bias, not an epipolar error; only the second-order
   row shift ``angle * (u - cx)(v - cy) / f`` shows it, which a residual distortion or a
   rectification error of a tenth of a pixel mimics. It is fitted with the other two (fixing it
   at zero while the matches show one would bias roll) and applied only when its interval is
   narrower than :attr:`CorrectionConfig.yaw_max_interval_deg` and excludes zero.

No correction (``CorrectionResult.correction is None``, with the reason) from fewer than
:attr:`CorrectionConfig.min_pairs` pairs, from matches that cover too little of the image, from
an interval wider than :attr:`CorrectionConfig.max_interval_deg` (the rotation is not determined),
or when the observable rotation is not at least :attr:`CorrectionConfig.min_correction_deg` beyond
its interval (nothing to correct).

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
from sepfm_ros.geometry.calibrated.correction_config import (  # light: the node's parameters
    CorrectionConfig as CorrectionConfig,
)
from sepfm_ros.geometry.epipolar import homogeneous


@dataclass
class _Pair:
    pts_a: np.ndarray
    pts_b: np.ndarray
    first: np.ndarray  # (N,) bool: the matches of the first fit
    fits: dict[int, object] = field(default_factory=dict)  # id(calib) -> _PairFit


class CorrectionWindow:
    """The matches of the last ``window`` usable pairs, for the rotation fit.

    Matches are in the estimator's pixels (undistorted pixels of K for raw images). The first
    fit of a pair uses the matches the calibration check fits (the estimated F's inliers plus
    the band around the calibrated F: ``first``); the later fits reselect among all the pair's
    matches around the fitted rotation.
    """

    def __init__(self, window: int = 40, min_matches: int = 20) -> None:
        if int(window) < 1:
            raise ValueError(f"correction window must be >= 1, got {window}")
        self.min_matches = int(min_matches)
        self._pairs: deque[_Pair] = deque(maxlen=int(window))

    def add(self, pts_a: np.ndarray, pts_b: np.ndarray, first: np.ndarray | None = None) -> bool:
        """Keep one pair's (N, 2) matches; False (not kept) with fewer than ``min_matches``
        in ``first``. ``first``: (N,) bool, the matches of the first fit (default: all)."""
        a = np.asarray(pts_a, dtype=np.float64).reshape(-1, 2)
        b = np.asarray(pts_b, dtype=np.float64).reshape(-1, 2)
        sel = np.ones(len(a), bool) if first is None else np.asarray(first, bool).reshape(-1)
        if not len(a) == len(b) == len(sel):
            raise ValueError(
                f"pts_a, pts_b and first differ in length: {len(a)}, {len(b)}, {len(sel)}"
            )
        good = np.all(np.isfinite(a), axis=1) & np.all(np.isfinite(b), axis=1)
        if np.count_nonzero(good & sel) < self.min_matches:
            return False
        self._pairs.append(_Pair(a[good].copy(), b[good].copy(), sel[good].copy()))
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
    basis = _basis(fixed_axis)
    p0 = np.zeros(basis.shape[1]) if start is None else basis.T @ np.asarray(start)

    def fun(p: np.ndarray) -> np.ndarray:
        return correction_residuals(basis @ p, E, xa, xb, Ka_inv, Kb_inv)

    sol = least_squares(fun, p0, loss="soft_l1", f_scale=float(scale_px), x_scale=1e-3)
    return np.asarray(basis @ sol.x)


def _basis(fixed_axis: np.ndarray | None) -> np.ndarray:
    """(3, k): the rotation vectors fitted (k = 3, or 2 normal to ``fixed_axis``)."""
    if fixed_axis is None:
        return np.eye(3)
    return np.asarray(np.linalg.svd(np.asarray(fixed_axis, dtype=np.float64)[None])[2][1:].T)


def _essential(calib: StereoCalibration) -> np.ndarray:
    t = np.asarray(calib.t, dtype=np.float64)
    t = t / np.linalg.norm(t)
    return np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]]) @ calib.R


@dataclass(frozen=True)
class _PairFit:
    """One pair's fit: its rotation vector (3,) rad, and the information ``J^T J`` (3, 3,
    px^2/rad^2) of its n selected matches there."""

    free: np.ndarray
    info: np.ndarray
    n: int


def refit(
    calib: StereoCalibration,
    pts_a: np.ndarray,
    pts_b: np.ndarray,
    start: np.ndarray,
    config: CorrectionConfig,
    fixed_axis: np.ndarray | None = None,
    rounds: int = 2,
) -> tuple[np.ndarray, np.ndarray]:
    """Refit ``rounds`` times on the matches within ``config.band_px`` (Sampson, px) of the
    current rotation, from ``start`` (3,). Returns (rotation vector (3,) rad, (N,) bool used)."""
    E = _essential(calib)
    xa, xb = homogeneous(pts_a), homogeneous(pts_b)
    Ka_inv, Kb_inv = np.linalg.inv(calib.model_a.K), np.linalg.inv(calib.model_b.K)
    omega = np.asarray(start, dtype=np.float64)
    sel = np.ones(len(xa), bool)
    for _ in range(rounds):
        d = np.abs(correction_residuals(omega, E, xa, xb, Ka_inv, Kb_inv))
        if np.count_nonzero(d < config.band_px) < 5:
            break
        sel = d < config.band_px
        omega = fit_rotation(calib, pts_a[sel], pts_b[sel], config.scale_px, fixed_axis, omega)
    return omega, sel


def information(
    calib: StereoCalibration, pts_a: np.ndarray, pts_b: np.ndarray, omega: np.ndarray
) -> np.ndarray:
    """(3, 3) ``J^T J`` of the Sampson residuals (px) in the rotation vector (rad) at omega."""
    E = _essential(calib)
    xa, xb = homogeneous(pts_a), homogeneous(pts_b)
    Ka_inv, Kb_inv = np.linalg.inv(calib.model_a.K), np.linalg.inv(calib.model_b.K)
    h = 1e-6
    J = np.stack(
        [
            (
                correction_residuals(omega + h * e, E, xa, xb, Ka_inv, Kb_inv)
                - correction_residuals(omega - h * e, E, xa, xb, Ka_inv, Kb_inv)
            )
            / (2 * h)
            for e in np.eye(3)
        ],
        axis=1,
    )
    return np.asarray(J.T @ J)


def _pair_fit(calib: StereoCalibration, pair: _Pair, config: CorrectionConfig) -> _PairFit:
    """The pair's fits, cached per calibration (object identity)."""
    key = id(calib)
    if key not in pair.fits:
        first = fit_rotation(calib, pair.pts_a[pair.first], pair.pts_b[pair.first], config.scale_px)
        free, sel = refit(calib, pair.pts_a, pair.pts_b, first, config)
        info = information(calib, pair.pts_a[sel], pair.pts_b[sel], free)
        pair.fits = {key: _PairFit(free, info, int(np.count_nonzero(sel)))}
    fit = pair.fits[key]
    assert isinstance(fit, _PairFit)
    return fit


def pair_rotations(
    calib: StereoCalibration, window: CorrectionWindow, config: CorrectionConfig
) -> np.ndarray:
    """(n, 3) each pair's own rotation vector of camera b (rad, b's frame), as
    :func:`estimate_correction` fits them (yaw included): their mean is a window's rotation
    without the decisions of :func:`estimate_correction` (e.g. a clean sequence's reading)."""
    return np.array([_pair_fit(calib, p, config).free for p in window.pairs]).reshape(-1, 3)


def _coverage(calib: StereoCalibration, pts_b: np.ndarray) -> float:
    """Smaller of the matches' robust extents in b's image (5-95th percentile) over its size."""
    lo, hi = np.percentile(pts_b, [5, 95], axis=0)
    w, h = calib.model_b.size
    return float(min((hi[0] - lo[0]) / w, (hi[1] - lo[1]) / h))


def _observable(v: np.ndarray, weak: np.ndarray) -> np.ndarray:
    return np.asarray(v - np.outer(v @ weak, weak) if v.ndim == 2 else v - (v @ weak) * weak)


def _half_widths(
    fits: np.ndarray,
    info: np.ndarray,
    n_matches: int,
    basis: np.ndarray,
    config: CorrectionConfig,
    focal_px: float,
) -> np.ndarray:
    """(3,) 95 % half-widths (deg) of the mean of the (n, 3) per-pair fits (rad): Student's t
    over the pairs, and the systematic floor in quadrature, for rotations in ``basis`` (3, k);
    ``focal_px``: camera b's focal length (px), which turns the floor's angle into pixels."""
    n = len(fits)
    stat = float(student_t.ppf(0.975, n - 1)) * fits.std(axis=0, ddof=1) / np.sqrt(n)
    sub = basis.T @ info @ basis / max(n_matches, 1)
    cov = basis @ np.linalg.pinv(sub) @ basis.T
    sys_px = config.systematic_mrad * 1e-3 * focal_px
    sys = sys_px * np.sqrt(np.clip(np.diag(cov), 0.0, None))
    return np.asarray(np.degrees(np.sqrt(stat**2 + sys**2)))


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
    pair_fits = [_pair_fit(calib, p, config) for p in pairs]
    free = np.array([f.free for f in pair_fits])  # (n, 3) rad
    obs = _observable(free, weak)
    # the reference is the newest min_pairs pairs' median: pairs from before a change of the
    # rig are dropped like bad pairs, and the correction follows the rig as it is now
    dev = np.linalg.norm(obs - np.median(obs[-config.min_pairs :], axis=0), axis=1)
    mad = 1.4826 * float(np.median(dev))
    keep = dev <= config.outlier_sigma * max(mad, np.radians(config.outlier_floor_deg))
    n = int(np.count_nonzero(keep))
    if n < config.min_pairs:
        return CorrectionResult(
            None,
            f"too few consistent pairs for a correction: {n} of {len(pairs)} agree "
            f"(need {config.min_pairs})",
        )
    kept = [f for f, k in zip(pair_fits, keep, strict=True) if k]
    coverage = _coverage(
        calib, np.concatenate([p.pts_b for p, k in zip(pairs, keep, strict=True) if k])
    )
    if coverage < config.min_coverage:
        return CorrectionResult(
            None,
            f"degenerate window: the matches span {coverage:.0%} of the image "
            f"(need {config.min_coverage:.0%}); no texture over most of it",
        )
    info = np.sum([f.info for f in kept], axis=0)
    n_matches = int(sum(f.n for f in kept))
    mean = free[keep].mean(axis=0)
    focal = float(np.mean(np.diag(calib.model_b.K)[:2]))
    half = _half_widths(free[keep], info, n_matches, np.eye(3), config, focal)
    weak_index = int(np.argmax(np.abs(weak)))
    strong = [i for i in range(3) if i != weak_index]
    yaw_free = float(np.degrees(mean @ weak))
    yaw_half = float(half[weak_index])
    yaw_determined = yaw_half <= config.yaw_max_interval_deg and abs(yaw_free) > yaw_half
    # yaw is fitted with the others (fixing it at zero while the matches show one would bias
    # roll) but applied only when determined
    omega = mean if yaw_determined else mean - (mean @ weak) * weak
    axes = np.degrees(omega)
    if np.any(half[strong] > config.max_interval_deg):
        return CorrectionResult(
            None,
            "degenerate window: the matches do not determine the rotation (95 % interval "
            f"{np.max(half[strong]):.3f} deg > {config.max_interval_deg} deg: too few or too "
            "poor matches?)",
        )
    # the observable rotation the interval guarantees (95 %): each axis less its half-width
    shown = float(np.linalg.norm(np.clip(np.abs(axes[strong]) - half[strong], 0.0, None)))
    figures = (
        f"pitch {axes[0]:+.3f} +- {half[0]:.3f}, roll {axes[2]:+.3f} +- {half[2]:.3f} deg, "
        f"yaw {yaw_free:+.3f} +- {yaw_half:.3f} deg"
    )
    if not yaw_determined and shown < config.min_correction_deg:
        return CorrectionResult(
            None, f"no correction needed: the matches agree with the calibration ({figures})"
        )
    dR = Rotation.from_rotvec(omega).as_matrix()
    correction = RigCorrection(
        dR @ calib.R,
        dR @ np.asarray(calib.t, dtype=np.float64),
        axes,
        half,
        yaw_determined,
        n,
        n_matches,
        yaw_free,
    )
    return CorrectionResult(
        correction,
        f"corrected from {n} pairs ({n_matches} matches, {len(pairs) - n} dropped): {figures} "
        + ("corrected" if yaw_determined else "kept at the calibration"),
    )
