"""The covariance of a relative pose estimated from matches: Gauss-Newton on the inliers. No ROS.

A relative pose (R, t) with ``X_b = R X_a + t`` and unit t has 5 degrees of freedom, perturbed as
the refinement of :func:`~sepfm_ros.geometry.calibrated.pose.refine_pose` perturbs it:

- ``delta`` (3, radians): ``R' = exp([delta]_x) R``, a rotation vector in camera b's frame;
- ``eta`` (2, unit-free): ``t' = (t + B eta) / |t + B eta|`` with ``B`` (3, 2) an orthonormal
  basis of the plane normal to t (so ``B eta`` is, to first order, the direction's change in
  radians).

With the signed Sampson distances r (px) of the n inliers and their Jacobian J (n, 5) at the
pose, the covariance of (delta, eta) is ``sigma^2 (J^T J)^-1`` with ``sigma^2 = sum(r^2) /
(n - 5)`` (px^2): the inliers' own scatter, nothing assumed about the feature detector.
:func:`pose_in_a_covariance` carries it to the pose of camera b in camera a's frame (what
``~/relative_pose`` publishes), :meth:`PoseCovariance.direction_in_a` to the translation
direction and :meth:`PoseCovariance.rotation_in_a` to the rotation seen from camera a.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from sepfm_ros.geometry.epipolar import homogeneous, skew

# parameters of the pose: 3 of the rotation, 2 of the translation's direction
POSE_DOF = 5
# central-difference step of the Jacobian (radians / unit-free): the Sampson distance is smooth
# and of order 1 px, so 1e-6 keeps both the truncation and the rounding error under 1e-6 px
JACOBIAN_STEP = 1e-6


def sampson_residuals(
    R: np.ndarray,
    t: np.ndarray,
    xa: np.ndarray,
    xb: np.ndarray,
    Ka_inv: np.ndarray,
    Kb_inv: np.ndarray,
) -> np.ndarray:
    """Signed Sampson distances (px) of homogeneous pixel matches xa, xb (N, 3) under the pose."""
    F = Kb_inv.T @ skew(t) @ R @ Ka_inv
    Fx = xa @ F.T
    Ftx = xb @ F
    r = np.einsum("ij,ij->i", xb, Fx)
    den = np.sqrt(Fx[:, 0] ** 2 + Fx[:, 1] ** 2 + Ftx[:, 0] ** 2 + Ftx[:, 1] ** 2)
    return r / np.maximum(den, 1e-12)


def tangent_basis(t: np.ndarray) -> np.ndarray:
    """(3, 2) orthonormal basis of the plane normal to the (3,) vector t."""
    t0 = np.asarray(t, dtype=np.float64) / np.linalg.norm(t)
    return np.linalg.svd(t0[None])[2][1:].T


def perturbed(
    R: np.ndarray, t: np.ndarray, basis: np.ndarray, p: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The pose moved by p = (delta (3), eta (2)) as in the module docstring; t unit."""
    Rp = Rotation.from_rotvec(p[:3]).as_matrix() @ R
    tp = np.asarray(t, dtype=np.float64) / np.linalg.norm(t) + basis @ p[3:5]
    return Rp, tp / np.linalg.norm(tp)


@dataclass(frozen=True)
class PoseCovariance:
    """Covariance of a relative pose's 5 parameters (module docstring).

    Attributes:
        cov: (5, 5) covariance of (delta (rad), eta (rad)).
        R: (3, 3) the pose's rotation (a -> b) it was computed at.
        t: (3,) the pose's unit translation.
        basis: (3, 2) the basis B of eta.
        sigma_px: the inliers' residual scale sqrt(sum r^2 / (n - 5)) (px).
        n_points: inliers used.
    """

    cov: np.ndarray
    R: np.ndarray
    t: np.ndarray
    basis: np.ndarray
    sigma_px: float
    n_points: int

    def rotation_in_a(self) -> np.ndarray:
        """(3, 3) covariance (rad^2) of the rotation of camera b in a's frame, as a rotation
        vector in a's frame: ``R_ba = R^T`` perturbed to ``exp([eps]_x) R^T``, ``eps = -R^T
        delta``."""
        return self.R.T @ self.cov[:3, :3] @ self.R

    def direction_jacobian(self) -> np.ndarray:
        """(3, 5) derivative of the direction of b's centre seen from a, ``d = -R^T t``, by
        (delta, eta)."""
        return np.hstack([-self.R.T @ skew(self.t), -self.R.T @ self.basis])

    def direction_in_a(self) -> np.ndarray:
        """(3, 3) covariance (rad^2, rank 2, normal to d) of the unit direction ``d = -R^T t``
        of camera b's centre in camera a's frame."""
        J = self.direction_jacobian()
        return J @ self.cov @ J.T

    def rotation_bound_deg(self, error: np.ndarray, chi2: float) -> float:
        """The radius (deg) of the ellipsoid ``delta^T cov^-1 delta = chi2`` along ``error``
        (a rotation vector of R's frame, rad): the bound this covariance sets on that error."""
        return _ellipsoid_radius_deg(self.cov[:3, :3], error, chi2)

    def direction_bound_deg(self, error: np.ndarray, chi2: float) -> float:
        """The same for a direction error ``eta`` (2, rad in the basis)."""
        return _ellipsoid_radius_deg(self.cov[3:5, 3:5], error, chi2)


def _ellipsoid_radius_deg(cov: np.ndarray, error: np.ndarray, chi2: float) -> float:
    norm = float(np.linalg.norm(error))
    if norm == 0.0:
        return float(np.degrees(np.sqrt(chi2 * np.max(np.linalg.eigvalsh(cov)))))
    u = np.asarray(error, dtype=np.float64) / norm
    m2 = float(u @ np.linalg.solve(cov, u))
    return float(np.degrees(np.sqrt(chi2 / m2)))


def sampson_jacobian(
    R: np.ndarray,
    t: np.ndarray,
    basis: np.ndarray,
    pts_a: np.ndarray,
    pts_b: np.ndarray,
    K_a: np.ndarray,
    K_b: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """The Sampson distances (n,) px of (n, 2) pixel matches and their Jacobian (n, 5) by
    (delta, eta), by central differences."""
    xa, xb = homogeneous(pts_a), homogeneous(pts_b)
    Ka_inv, Kb_inv = np.linalg.inv(K_a), np.linalg.inv(K_b)
    r0 = sampson_residuals(R, t, xa, xb, Ka_inv, Kb_inv)
    J = np.empty((len(r0), POSE_DOF))
    for k in range(POSE_DOF):
        step = np.zeros(POSE_DOF)
        step[k] = JACOBIAN_STEP
        plus = sampson_residuals(*perturbed(R, t, basis, step), xa, xb, Ka_inv, Kb_inv)
        minus = sampson_residuals(*perturbed(R, t, basis, -step), xa, xb, Ka_inv, Kb_inv)
        J[:, k] = (plus - minus) / (2 * JACOBIAN_STEP)
    return r0, J


def _phi(c: float) -> float:
    """The standard normal density at ``c``."""
    return math.exp(-0.5 * c * c) / math.sqrt(2.0 * math.pi)


def _Phi(c: float) -> float:
    """The standard normal distribution function at ``c``."""
    return 0.5 * (1.0 + math.erf(c / math.sqrt(2.0)))


def truncated_sigma(rms: float, cut: float) -> float:
    """The std sigma of a zero-mean Gaussian whose values within +-cut have this rms.

    Inliers are the matches whose residual is within the cut, so their rms underestimates the
    noise: a Gaussian cut at +-c sigma keeps the variance ``sigma^2 g(c)``, ``g(c) = 1 - 2 c
    phi(c) / (2 Phi(c) - 1)`` (0.77 at c = 2). Solved for sigma by bisection on c; an rms at
    or above ``cut / sqrt(3)`` (residuals spread evenly over the cut, no Gaussian fits) gives
    ``cut`` (a conservative scale: the matches do not show their noise).
    """
    if not cut > 0 or not rms > 0:
        return float(rms)
    ratio = (rms / cut) ** 2
    if ratio >= 1.0 / 3.0 - 1e-9:
        return float(cut)

    def kept(c: float) -> float:  # (rms / cut)^2 of a Gaussian cut at c sigma
        return float((1 - 2 * c * _phi(c) / (2 * _Phi(c) - 1)) / c**2)

    lo, hi = 1e-3, 60.0  # kept() falls from 1/3 to 0 over c in (0, inf)
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if kept(mid) > ratio else (lo, mid)
    return float(cut / (0.5 * (lo + hi)))


def cut_variance_factor(c: float) -> float:
    """Variance of a least-squares fit on the residuals within +-c sigma that the fit itself
    selects, over that of a fit on all residuals with the same (inlier) Jacobian.

    The fit is an M-estimator with psi(r) = r 1{|r| < c sigma}; its sandwich variance is
    ``sigma^2 E[psi^2] / E[psi']^2`` per match, E[psi'] = P - 2 c phi(c) (the cut's boundary
    term: a match that crosses the cut leaves the fit), P = 2 Phi(c) - 1 the share kept. Per
    kept match (J^T J summed over the inliers) that is ``g(c) P^2 / (P - 2 c phi(c))^2``
    (1.29 at c = 2; 1 as c grows).
    """
    P = 2 * _Phi(c) - 1
    g = 1 - 2 * c * _phi(c) / P
    slope = P - 2 * c * _phi(c)
    if not slope > 0:
        return math.inf
    return float(g * P**2 / slope**2)


def pose_covariance(
    R: np.ndarray,
    t: np.ndarray,
    pts_a: np.ndarray,
    pts_b: np.ndarray,
    K_a: np.ndarray,
    K_b: np.ndarray,
    cut_px: float | None = None,
) -> PoseCovariance | None:
    """Covariance of a relative pose from its inliers: ``sigma^2 (J^T J)^-1`` (module docstring).

    Args:
        R, t: the pose (``X_b = R X_a + t``), at the least-squares optimum of these matches.
        pts_a, pts_b: (n, 2) the pose's inlier matches, undistorted pixels of K_a / K_b.
        cut_px: the Sampson distance (px) the inliers were selected under; sigma is then the
            Gaussian scale whose cut residuals have the inliers' rms (:func:`truncated_sigma`).
    Returns:
        The covariance, or None with n <= 5 or a Jacobian of rank below 5 (no motion to
        observe the pose by, e.g. all inliers at one point).
    """
    pts_a = np.asarray(pts_a, dtype=np.float64).reshape(-1, 2)
    pts_b = np.asarray(pts_b, dtype=np.float64).reshape(-1, 2)
    n = len(pts_a)
    if n <= POSE_DOF:
        return None
    t = np.asarray(t, dtype=np.float64).reshape(3)
    t = t / np.linalg.norm(t)
    basis = tangent_basis(t)
    r, J = sampson_jacobian(R, t, basis, pts_a, pts_b, K_a, K_b)
    JtJ = J.T @ J
    if not np.all(np.isfinite(JtJ)) or np.linalg.matrix_rank(JtJ) < POSE_DOF:
        return None
    sigma2 = float(r @ r) / (n - POSE_DOF)
    factor = 1.0
    if cut_px is not None:
        sigma2 = truncated_sigma(float(np.sqrt(sigma2)), float(cut_px)) ** 2
        factor = cut_variance_factor(float(cut_px) / np.sqrt(sigma2))
    cov = factor * sigma2 * np.linalg.inv(JtJ)
    cov = (cov + cov.T) / 2
    return PoseCovariance(cov, np.asarray(R, float), t, basis, float(np.sqrt(sigma2)), n)


def pose_in_a_covariance(cov: PoseCovariance, length: float) -> np.ndarray:
    """(6, 6) covariance of the pose of camera b in camera a's frame, ROS order (x, y, z in
    metres; rotation about a's fixed x, y, z axes in radians), for a translation of ``length``
    metres (a stereo rig's calibrated baseline).

    The matches observe the translation's direction, not its length: the position's covariance
    across the baseline is ``length^2`` times the direction's; along it, the length comes from
    the calibration, which carries no uncertainty of its own, and gets the mean of the two
    variances across it (the position is then as uncertain along the baseline as across it,
    and the matrix positive definite).
    """
    J = np.zeros((6, POSE_DOF))
    J[:3] = length * cov.direction_jacobian()
    J[3:, :3] = -cov.R.T
    out = J @ cov.cov @ J.T
    d = -cov.R.T @ cov.t
    out[:3, :3] += (np.trace(out[:3, :3]) / 2) * np.outer(d, d)
    return (out + out.T) / 2


def direction_error(t_est: np.ndarray, t_ref: np.ndarray, basis: np.ndarray) -> np.ndarray:
    """(2,) eta taking unit t_est to the direction of t_ref (log map on the sphere, rad)."""
    a = np.asarray(t_est, dtype=np.float64) / np.linalg.norm(t_est)
    b = np.asarray(t_ref, dtype=np.float64) / np.linalg.norm(t_ref)
    angle = float(np.arccos(np.clip(a @ b, -1.0, 1.0)))
    tangent = b - (a @ b) * a
    norm = float(np.linalg.norm(tangent))
    if norm == 0.0:
        return np.zeros(2)
    return np.asarray(basis.T @ (tangent / norm) * angle)


def rotation_error(R_est: np.ndarray, R_ref: np.ndarray) -> np.ndarray:
    """(3,) delta with ``R_est = exp([delta]_x) R_ref`` (rad)."""
    return np.asarray(Rotation.from_matrix(np.asarray(R_est) @ np.asarray(R_ref).T).as_rotvec())
