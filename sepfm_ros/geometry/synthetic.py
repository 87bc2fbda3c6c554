"""Synthetic two-view scenes with exact ground truth (for tests, demos and benchmarks)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sepfm_ros.geometry.epipolar import fundamental_from_cameras


@dataclass(frozen=True)
class SyntheticPair:
    """pts1, pts2: (N, 2) px; F: GT (3, 3); is_inlier: (N,) bool; on_line: (N,) bool (3D-line
    points); P1, P2: (3, 4) cameras; image_size: (width, height)."""

    pts1: np.ndarray
    pts2: np.ndarray
    F: np.ndarray
    is_inlier: np.ndarray
    on_line: np.ndarray
    P1: np.ndarray
    P2: np.ndarray
    image_size: tuple[int, int]


def look_at_camera(K: np.ndarray, center: np.ndarray, target: np.ndarray) -> np.ndarray:
    """3x4 camera K [R | -R C] at ``center`` looking at ``target`` (y axis roughly down)."""
    z = target - center
    z = z / np.linalg.norm(z)
    up = np.array([0.0, -1.0, 0.0])
    x = np.cross(up, z)
    if np.linalg.norm(x) < 1e-9:
        x = np.array([1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    return K @ np.concatenate([R, (-R @ center)[:, None]], axis=1)


def _project(P: np.ndarray, X: np.ndarray) -> np.ndarray:
    x = np.concatenate([X, np.ones((len(X), 1))], axis=1) @ P.T
    return x[:, :2] / x[:, 2:3]


def make_pair(
    n_inliers: int = 200,
    n_outliers: int = 0,
    n_lines: int = 2,
    points_per_line: int = 12,
    noise: float = 0.0,
    image_size: tuple[int, int] = (640, 480),
    baseline: float = 1.0,
    seed: int | None = 0,
) -> SyntheticPair:
    """Random cameras viewing random 3D points, some sampled on 3D lines, plus outliers.

    Args:
        n_inliers: true correspondences in general position (in addition to line points).
        n_outliers: random wrong correspondences (uniform in both images).
        n_lines: 3D lines; each contributes ``points_per_line`` true correspondences.
        noise: Gaussian pixel noise (std, px) added to every true correspondence.
        baseline: camera distance relative to the scene size.
    Returns:
        A :class:`SyntheticPair`; matches are shuffled.
    """
    rng = np.random.default_rng(seed)
    w, h = image_size
    f = 0.9 * w
    K = np.array([[f, 0.0, w / 2.0], [0.0, f, h / 2.0], [0.0, 0.0, 1.0]])
    target = np.array([0.0, 0.0, 6.0])
    C1 = rng.normal(0.0, 0.3, 3)
    d = rng.normal(0.0, 1.0, 3)
    d[2] *= 0.3
    C2 = C1 + baseline * d / np.linalg.norm(d)
    P1 = look_at_camera(K, C1, target + rng.normal(0, 0.2, 3))
    P2 = look_at_camera(K, C2, target + rng.normal(0, 0.2, 3))

    def visible(X: np.ndarray) -> np.ndarray:
        ok = np.ones(len(X), dtype=bool)
        for P in (P1, P2):
            x = _project(P, X)
            depth = np.concatenate([X, np.ones((len(X), 1))], axis=1) @ P[2]
            inside = (x[:, 0] > 1) & (x[:, 0] < w - 2) & (x[:, 1] > 1) & (x[:, 1] < h - 2)
            ok &= (depth > 0) & inside
        return ok

    def sample_points(m: int) -> np.ndarray:
        out = np.zeros((0, 3))
        while len(out) < m:
            X = target + rng.uniform(-2.5, 2.5, (4 * m + 16, 3)) * np.array([1.0, 0.8, 1.0])
            out = np.concatenate([out, X[visible(X)]])
        return out[:m]

    Xg = sample_points(n_inliers)
    line_pts = []
    for _ in range(n_lines):
        for _attempt in range(200):
            A = sample_points(1)[0]
            B = sample_points(1)[0]
            if np.linalg.norm(B - A) < 1.5:
                continue
            s = rng.uniform(0, 1, 4 * points_per_line)
            X = A + s[:, None] * (B - A)
            X = X[visible(X)]
            if len(X) >= points_per_line:
                line_pts.append(X[:points_per_line])
                break
    Xl = np.concatenate(line_pts) if line_pts else np.zeros((0, 3))
    X = np.concatenate([Xg, Xl])
    on_line = np.concatenate([np.zeros(len(Xg), bool), np.ones(len(Xl), bool)])
    x1 = _project(P1, X) + rng.normal(0.0, noise, (len(X), 2)) * (noise > 0)
    x2 = _project(P2, X) + rng.normal(0.0, noise, (len(X), 2)) * (noise > 0)
    o1 = rng.uniform([0, 0], [w - 1, h - 1], (n_outliers, 2))
    o2 = rng.uniform([0, 0], [w - 1, h - 1], (n_outliers, 2))
    pts1 = np.concatenate([x1, o1])
    pts2 = np.concatenate([x2, o2])
    inl = np.concatenate([np.ones(len(X), bool), np.zeros(n_outliers, bool)])
    on_line = np.concatenate([on_line, np.zeros(n_outliers, bool)])
    perm = rng.permutation(len(pts1))
    return SyntheticPair(
        pts1[perm],
        pts2[perm],
        fundamental_from_cameras(P1, P2),
        inl[perm],
        on_line[perm],
        P1,
        P2,
        (w, h),
    )
