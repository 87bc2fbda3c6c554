"""Epipolar helpers: distances, normalisation, F from cameras. Batched numpy, no ROS."""

from __future__ import annotations

import numpy as np


def homogeneous(pts: np.ndarray) -> np.ndarray:
    """(N, 2) -> (N, 3) with a trailing 1."""
    return np.concatenate([pts, np.ones((pts.shape[0], 1))], axis=1)


def skew(v: np.ndarray) -> np.ndarray:
    """(3,) -> (3, 3) cross-product matrix [v]_x."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def normalize_fundamental(F: np.ndarray) -> np.ndarray:
    """Scale F (..., 3, 3) to unit Frobenius norm with its largest-magnitude entry positive."""
    F = np.asarray(F, dtype=np.float64)
    flat = F.reshape(*F.shape[:-2], 9)
    norm = np.linalg.norm(flat, axis=-1, keepdims=True)
    idx = np.argmax(np.abs(flat), axis=-1)[..., None]
    sign = np.sign(np.take_along_axis(flat, idx, axis=-1))
    sign = np.where(sign == 0, 1.0, sign)
    return (flat * sign / np.where(norm == 0, 1.0, norm)).reshape(F.shape)


def enforce_rank2(F: np.ndarray) -> np.ndarray:
    """Closest rank-2 matrix (Frobenius) to F (..., 3, 3) by zeroing the smallest singular value."""
    U, s, Vt = np.linalg.svd(F)
    s = s.copy()
    s[..., 2] = 0.0
    return (U * s[..., None, :]) @ Vt


def _epipolar_terms(F: np.ndarray, pts1: np.ndarray, pts2: np.ndarray):
    """Per-model algebraic residuals and the first two coordinates of the epipolar lines.

    F: (3, 3) or (M, 3, 3); pts: (N, 2). Returns (r, a2, b2, a1, b1), each (M, N): r = x2^T F x1,
    (a2, b2) of l2 = F x1 (lines in image 2), (a1, b1) of l1 = F^T x2 (lines in image 1).
    """
    Fs = F[None] if F.ndim == 2 else F
    x1 = homogeneous(pts1).T  # (3, N)
    x2 = homogeneous(pts2).T
    l2 = Fs @ x1  # (M, 3, N), batched BLAS
    l1 = np.swapaxes(Fs, 1, 2)[:, :2] @ x2  # only the first two rows are needed
    r = (l2 * x2).sum(axis=1)
    return r, l2[:, 0], l2[:, 1], l1[:, 0], l1[:, 1]


def symmetric_epipolar_distance(F: np.ndarray, pts1: np.ndarray, pts2: np.ndarray) -> np.ndarray:
    """Symmetric epipolar distance in pixels: the mean of the two point-to-epipolar-line distances.

    d = (|x2^T F x1| / ||(F x1)_{1:2}|| + |x2^T F x1| / ||(F^T x2)_{1:2}||) / 2.

    Args:
        F: (3, 3) or (M, 3, 3) fundamental matrices with x2^T F x1 = 0.
        pts1, pts2: (N, 2) pixel coordinates in image 1 and image 2.
    Returns:
        (N,) for a single F, (M, N) for a batch; inf where an epipolar line is undefined.
    """
    r, a2, b2, a1, b1 = _epipolar_terms(np.asarray(F, dtype=np.float64), pts1, pts2)
    with np.errstate(divide="ignore", invalid="ignore"):
        d = 0.5 * np.abs(r) * (1.0 / np.sqrt(a2 * a2 + b2 * b2) + 1.0 / np.sqrt(a1 * a1 + b1 * b1))
    d = np.where(np.isfinite(d), d, np.inf)
    return d[0] if np.asarray(F).ndim == 2 else d


def sampson_distance(F: np.ndarray, pts1: np.ndarray, pts2: np.ndarray) -> np.ndarray:
    """Sampson distance in pixels (first-order geometric error, square-rooted).

    d = |x2^T F x1| / sqrt((F x1)_1^2 + (F x1)_2^2 + (F^T x2)_1^2 + (F^T x2)_2^2).

    Shapes as :func:`symmetric_epipolar_distance`.
    """
    r, a2, b2, a1, b1 = _epipolar_terms(np.asarray(F, dtype=np.float64), pts1, pts2)
    den = a2 * a2 + b2 * b2 + a1 * a1 + b1 * b1
    with np.errstate(divide="ignore", invalid="ignore"):
        d = np.abs(r) / np.sqrt(den)
    d = np.where(np.isfinite(d), d, np.inf)
    return d[0] if np.asarray(F).ndim == 2 else d


def camera_center(P: np.ndarray) -> np.ndarray:
    """Homogeneous centre (4,) of a finite or infinite 3x4 camera: the null vector of P."""
    _, _, Vt = np.linalg.svd(np.asarray(P, dtype=np.float64))
    return Vt[-1]


def fundamental_from_cameras(P1: np.ndarray, P2: np.ndarray) -> np.ndarray:
    """F with x2^T F x1 = 0 from two 3x4 cameras: F = [e2]_x P2 P1^+, e2 = P2 C1.

    Returned with unit Frobenius norm and its largest-magnitude entry positive.
    """
    P1 = np.asarray(P1, dtype=np.float64)
    P2 = np.asarray(P2, dtype=np.float64)
    e2 = P2 @ camera_center(P1)
    F = skew(e2) @ P2 @ np.linalg.pinv(P1)
    return normalize_fundamental(F)


def normalization_transform(pts: np.ndarray) -> np.ndarray:
    """Hartley's similarity T (3, 3): centroid to origin, mean distance to the origin sqrt(2).

    Args:
        pts: (N, 2) pixel coordinates, N >= 1.
    """
    c = pts.mean(axis=0)
    d = np.sqrt(((pts - c) ** 2).sum(axis=1)).mean()
    s = np.sqrt(2.0) / d if d > 0 else 1.0
    return np.array([[s, 0.0, -s * c[0]], [0.0, s, -s * c[1]], [0.0, 0.0, 1.0]])


def apply_transform(T: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Apply an affine 3x3 transform to (..., 2) points."""
    return pts @ T[:2, :2].T + T[:2, 2]


def denormalize(F_n: np.ndarray, T1: np.ndarray, T2: np.ndarray) -> np.ndarray:
    """F in pixels from F in normalised coordinates: F = T2^T F_n T1, batched over (..., 3, 3)."""
    return T2.T @ F_n @ T1
