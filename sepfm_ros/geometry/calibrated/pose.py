"""Relative pose from a fundamental matrix and calibrated cameras; calibrated stereo geometry.

Conventions (REP-103 optical frames: x right, y down, z forward). A relative pose (R, t) maps
coordinates of a 3D point in camera a's frame to camera b's frame: ``X_b = R X_a + t``, and
``E = [t]_x R`` with ``x_b^T E x_a = 0`` for normalised image points. The *pose of camera b in
camera a's frame* (what a ``TransformStamped`` with header a and child b carries) is its inverse,
``(R^T, -R^T t)``: see :func:`pose_of_b_in_a`.

Pixels are those the estimator used: undistorted pixels of K for raw images, rectified pixels
(K = P[:, :3]) for rectified ones (see :mod:`sepfm_ros.geometry.calibrated.camera`).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from sepfm_ros.geometry.calibrated.camera import CameraModel
from sepfm_ros.geometry.calibrated.pose_covariance import (
    PoseCovariance,
    pose_covariance,
    sampson_residuals,
)
from sepfm_ros.geometry.epipolar import homogeneous, normalize_fundamental, skew

# A relative pose is reported when at least this many inliers lie in front of both cameras.
MIN_POSE_POINTS = 5


@dataclass(frozen=True)
class RelativePose:
    """A relative pose estimated from F and the cameras.

    Attributes:
        R: (3, 3) rotation, a-frame -> b-frame (``X_b = R X_a + t``).
        t: (3,) translation, unit length (motion), or scaled (stereo, metres of the baseline).
        in_front: share of the used inliers in front of both cameras, in [0, 1].
        n_points: inliers used.
        status: "ok" or the reason there is no usable pose (then R = I, t = 0).
        covariance: the covariance of R and t's direction from the pose's inliers
            (:mod:`~sepfm_ros.geometry.calibrated.pose_covariance`), None when they do not
            determine it.
    """

    R: np.ndarray
    t: np.ndarray
    in_front: float
    n_points: int
    status: str = "ok"
    covariance: PoseCovariance | None = None

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    @property
    def rotation_deg(self) -> float:
        """Rotation angle between the two cameras (degrees)."""
        return rotation_angle_deg(self.R)

    def scaled(self, baseline: float) -> RelativePose:
        """The same pose with ``t`` scaled to length ``baseline`` (e.g. metres of a stereo rig)."""
        n = float(np.linalg.norm(self.t))
        t = self.t * (baseline / n) if n > 0 else self.t
        return RelativePose(self.R, t, self.in_front, self.n_points, self.status, self.covariance)


def essential_from_fundamental(F: np.ndarray, K_a: np.ndarray, K_b: np.ndarray) -> np.ndarray:
    """E = K_b^T F K_a, (3, 3) with unit Frobenius norm (x_b^T F x_a = 0 in pixels)."""
    E = np.asarray(K_b, dtype=np.float64).T @ np.asarray(F, dtype=np.float64) @ K_a
    return E / np.linalg.norm(E)


def fundamental_from_pose(
    R: np.ndarray, t: np.ndarray, K_a: np.ndarray, K_b: np.ndarray
) -> np.ndarray:
    """F = K_b^-T [t]_x R K_a^-1, normalised like every F of the package (unit norm, sign)."""
    F = np.linalg.inv(K_b).T @ skew(np.asarray(t, dtype=np.float64)) @ R @ np.linalg.inv(K_a)
    return normalize_fundamental(F)


def normalized_points(K: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """(N, 2) pixels -> (N, 2) normalised image coordinates K^-1 x (z = 1)."""
    x = homogeneous(np.asarray(pts, dtype=np.float64)) @ np.linalg.inv(K).T
    return x[:, :2] / x[:, 2:3]


def in_front_mask(R: np.ndarray, t: np.ndarray, na: np.ndarray, nb: np.ndarray) -> np.ndarray:
    """(N,) bool: the triangulated point of each normalised match has positive depth in both.

    Args:
        R, t: relative pose (``X_b = R X_a + t``); na, nb: (N, 2) normalised coordinates.
    """
    if len(na) == 0:
        return np.zeros(0, dtype=bool)
    P_a = np.eye(3, 4)
    P_b = np.concatenate([R, np.reshape(t, (3, 1))], axis=1)
    X = cv2.triangulatePoints(P_a, P_b, na.T.astype(np.float64), nb.T.astype(np.float64))
    w = X[3]
    with np.errstate(divide="ignore", invalid="ignore"):
        Xa = X[:3] / w
        za = Xa[2]
        zb = (R @ Xa + np.reshape(t, (3, 1)))[2]
    return np.isfinite(za) & np.isfinite(zb) & (za > 0) & (zb > 0)


def refine_pose(
    R: np.ndarray,
    t: np.ndarray,
    pts_a: np.ndarray,
    pts_b: np.ndarray,
    K_a: np.ndarray,
    K_b: np.ndarray,
    scale_px: float = 1.0,
    max_iterations: int = 20,
    fix_translation: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """Minimise the Sampson error (px, soft-L1 beyond ``scale_px``) over R (3 dof) and t (2 dof).

    Args:
        R, t: starting pose; pts_a, pts_b: (N, 2) pixel matches (N >= 5); K_a, K_b: intrinsics.
        fix_translation: keep t's direction and fit R only (3 dof): the calibration check's
            rotation, which a forward translation cannot absorb.
    Returns:
        (R (3, 3), t (3,) unit).
    """
    xa = homogeneous(pts_a)
    xb = homogeneous(pts_b)
    Ka_inv = np.linalg.inv(K_a)
    Kb_inv = np.linalg.inv(K_b)
    t0 = np.asarray(t, dtype=np.float64) / np.linalg.norm(t)
    # tangent basis of the unit sphere at t0
    basis = np.linalg.svd(t0[None])[2][1:].T  # (3, 2)

    def unpack(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        Rp = Rotation.from_rotvec(p[:3]).as_matrix() @ R
        if fix_translation:
            return Rp, t0
        tp = t0 + basis @ p[3:]
        return Rp, tp / np.linalg.norm(tp)

    def fun(p: np.ndarray) -> np.ndarray:
        return sampson_residuals(*unpack(p), xa, xb, Ka_inv, Kb_inv)

    n_params = 3 if fix_translation else 5
    sol = least_squares(
        fun,
        np.zeros(n_params),
        loss="soft_l1",
        f_scale=scale_px,
        max_nfev=max_iterations * (n_params + 1),
    )
    return unpack(sol.x)


def relative_pose(
    F: np.ndarray,
    pts_a: np.ndarray,
    pts_b: np.ndarray,
    K_a: np.ndarray,
    K_b: np.ndarray,
    inliers: np.ndarray | None = None,
    refine: bool = True,
    scale_px: float = 1.0,
    reselect: int = 2,
) -> RelativePose:
    """Relative pose of camera b w.r.t. camera a from F and the intrinsics.

    E = K_b^T F K_a is decomposed into its four (R, t) candidates; the one with the most inliers
    in front of both cameras wins (cheirality, ``cv2.recoverPose``), then (``refine``) R and t
    are refined on the inliers in front by minimising their Sampson error in pixels.

    Args:
        F: (3, 3) with x_b^T F x_a = 0 in the pixels of ``pts_a``/``pts_b``.
        pts_a, pts_b: (N, 2) matches in undistorted pixels of K_a / K_b.
        K_a, K_b: (3, 3) intrinsics of those pixels.
        inliers: (N,) bool mask of F's inliers (all when None).
        scale_px: soft-L1 scale of the refinement (px), e.g. the estimator's threshold; also
            the Sampson distance under which a match is re-selected as an inlier of the pose.
        reselect: rounds of re-selecting the inliers among all matches under the refined pose
            and refitting (0: refine on F's inliers only).
    Returns:
        A :class:`RelativePose` with unit t; status says why when no pose was found.
    """
    pts_a = np.asarray(pts_a, dtype=np.float64).reshape(-1, 2)
    pts_b = np.asarray(pts_b, dtype=np.float64).reshape(-1, 2)
    mask = np.ones(len(pts_a), bool) if inliers is None else np.asarray(inliers, bool)
    if not len(pts_a) == len(pts_b) == len(mask):
        raise ValueError(
            f"pts_a, pts_b and inliers differ in length: {len(pts_a)}, {len(pts_b)}, {len(mask)}"
        )
    pa, pb = pts_a[mask], pts_b[mask]
    n = len(pa)
    if F is None or n < MIN_POSE_POINTS:
        return RelativePose(np.eye(3), np.zeros(3), 0.0, n, f"too few inliers: {n}")
    E = essential_from_fundamental(F, K_a, K_b)
    na, nb = normalized_points(K_a, pa), normalized_points(K_b, pb)
    _, R, t, _ = cv2.recoverPose(E, na, nb, np.eye(3))
    t = t.reshape(3)
    front = in_front_mask(R, t, na, nb)
    if np.count_nonzero(front) < MIN_POSE_POINTS:
        return RelativePose(
            np.eye(3), np.zeros(3), float(front.mean()), n, "no pose puts the inliers in front"
        )
    used_a, used_b = pa[front], pb[front]
    if refine:
        R, t = refine_pose(R, t, used_a, used_b, K_a, K_b, scale_px)
        # the essential model (5 dof) is stricter than F (7 dof): re-select the inliers of all
        # matches under it (Sampson distance within scale_px, in front) and refit, twice
        for _ in range(reselect):
            sel = pose_inliers(R, t, pts_a, pts_b, K_a, K_b, scale_px)
            if np.count_nonzero(sel) < MIN_POSE_POINTS:
                break
            used_a, used_b = pts_a[sel], pts_b[sel]
            R, t = refine_pose(R, t, used_a, used_b, K_a, K_b, scale_px)
        front = in_front_mask(R, t, na, nb)
    t = t / np.linalg.norm(t)
    covariance = pose_covariance(R, t, used_a, used_b, K_a, K_b, scale_px)
    return RelativePose(R, t, float(front.mean()), n, covariance=covariance)


def pose_inliers(
    R: np.ndarray,
    t: np.ndarray,
    pts_a: np.ndarray,
    pts_b: np.ndarray,
    K_a: np.ndarray,
    K_b: np.ndarray,
    scale_px: float,
) -> np.ndarray:
    """(N,) bool: matches within ``scale_px`` (Sampson, px) of the pose and in front of both."""
    xa, xb = homogeneous(pts_a), homogeneous(pts_b)
    d = np.abs(sampson_residuals(R, t, xa, xb, np.linalg.inv(K_a), np.linalg.inv(K_b)))
    na, nb = normalized_points(K_a, pts_a), normalized_points(K_b, pts_b)
    return np.asarray((d < scale_px) & in_front_mask(R, t, na, nb))


def rotation_angle_deg(R: np.ndarray) -> float:
    """Angle (degrees) of a rotation matrix."""
    c = (np.trace(R) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def rotation_error_deg(R_est: np.ndarray, R_ref: np.ndarray) -> float:
    """Angle (degrees) of R_est R_ref^T: how far R_est is from R_ref."""
    return rotation_angle_deg(np.asarray(R_est) @ np.asarray(R_ref).T)


def direction_error_deg(t_est: np.ndarray, t_ref: np.ndarray) -> float:
    """Angle (degrees) between two translation directions (sign matters: cheirality fixes it)."""
    a = np.asarray(t_est, dtype=np.float64)
    b = np.asarray(t_ref, dtype=np.float64)
    c = a @ b / (np.linalg.norm(a) * np.linalg.norm(b))
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def pose_of_b_in_a(R: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The pose of camera b in a's frame, (R^T, -R^T t): rotation and position of b in a.

    This is the transform a ``geometry_msgs/TransformStamped`` with ``header.frame_id`` = a and
    ``child_frame_id`` = b carries (it maps b-coordinates to a-coordinates).
    """
    R = np.asarray(R, dtype=np.float64)
    return R.T, -R.T @ np.asarray(t, dtype=np.float64).reshape(3)


def pose_from_projections(
    P_a: np.ndarray, P_b: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Intrinsics and relative pose of two 3x4 cameras P = K [R | t] (any scale or sign).

    Returns:
        (K_a, K_b, R, t): K (3, 3) with K[2, 2] = 1 and positive focal lengths; R, t with
        ``X_b = R X_a + t`` (t in the units of the cameras' world frame).
    """
    out = []
    for P in (P_a, P_b):
        P = np.asarray(P, dtype=np.float64)
        if np.linalg.det(P[:, :3]) < 0:
            P = -P
        K, Rw, C = cv2.decomposeProjectionMatrix(P)[:3]
        C = C[:3, 0] / C[3, 0]
        out.append((K / K[2, 2], Rw, -Rw @ C))
    (K_a, R_a, t_a), (K_b, R_b, t_b) = out
    R = R_b @ R_a.T
    return K_a, K_b, R, t_b - R @ t_a


def rectified_offset(model: CameraModel) -> np.ndarray:
    """(3,) position offset t of the rectified camera: P = P[:, :3] [I | t] (metres)."""
    return np.linalg.solve(model.P[:, :3], model.P[:, 3])


def stereo_baseline(model_a: CameraModel, model_b: CameraModel) -> float:
    """Calibrated baseline (metres) of a stereo pair from the two P matrices.

    For the usual right camera (P_right[0, 3] = -fx' B, left P[:, 3] = 0) this is B.
    """
    return float(np.linalg.norm(rectified_offset(model_b) - rectified_offset(model_a)))


def stereo_pose(model_a: CameraModel, model_b: CameraModel) -> tuple[np.ndarray, np.ndarray]:
    """The calibrated relative pose (R, t) of a stereo pair, ``X_b = R X_a + t`` (metres).

    stereo_image_proc convention: R of each camera rotates its raw frame into the common
    rectified orientation; P = K' [I | t_rect] projects from the rectified left frame. For
    models of rectified images (:meth:`CameraModel.rectified`) R = I and the pose is a pure
    translation.
    """
    t_a, t_b = rectified_offset(model_a), rectified_offset(model_b)
    R = model_b.R.T @ model_a.R
    return R, model_b.R.T @ (t_b - t_a)


def stereo_fundamental(model_a: CameraModel, model_b: CameraModel) -> np.ndarray:
    """The calibrated F of a stereo pair, in the pixels the estimator sees.

    With raw models: undistorted pixels of K_a, K_b (points undistorted with
    :func:`~sepfm_ros.geometry.calibrated.camera.undistort_points`). With rectified models:
    rectified pixels. Normalised (unit Frobenius norm, largest entry positive).
    """
    R, t = stereo_pose(model_a, model_b)
    if np.linalg.norm(t) == 0:
        raise ValueError("the two cameras have the same centre: no stereo baseline in P")
    return fundamental_from_pose(R, t, model_a.K, model_b.K)
