"""The relative pose's covariance (sepfm_ros.geometry.calibrated.pose_covariance) on synthetic
cameras with known truth: it shrinks with more inliers and with less noise, its sigma is the
noise's, and its 95% bounds cover the true pose's error on a seeded set."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from sepfm_ros.geometry import estimate_fundamental
from sepfm_ros.geometry.calibrated.pose import pose_from_projections, relative_pose
from sepfm_ros.geometry.calibrated.pose_covariance import (
    direction_error,
    pose_covariance,
    pose_in_a_covariance,
    rotation_error,
    truncated_sigma,
)
from sepfm_ros.geometry.synthetic import make_pair


def _pose(n_inliers: int, noise: float, seed: int, n_outliers: int = 0):
    pair = make_pair(n_inliers=n_inliers, n_outliers=n_outliers, noise=noise, seed=seed)
    K_a, K_b, R_gt, t_gt = pose_from_projections(pair.P1, pair.P2)
    est = estimate_fundamental(pair.pts1, pair.pts2, pair.image_size, seed=0)
    pose = relative_pose(est.F, pair.pts1, pair.pts2, K_a, K_b, est.inliers)
    assert pose.ok and pose.covariance is not None
    return pose, R_gt, t_gt


def _size(pose) -> float:
    return float(np.trace(pose.covariance.cov))


def test_covariance_shrinks_with_more_inliers_and_less_noise():
    seeds = range(4)
    few = np.median([_size(_pose(40, 0.5, s)[0]) for s in seeds])
    many = np.median([_size(_pose(400, 0.5, s)[0]) for s in seeds])
    # ten times the matches: about a tenth of the variance (the scenes differ a little)
    assert many < 0.3 * few, (few, many)
    quiet = np.median([_size(_pose(200, 0.2, s)[0]) for s in seeds])
    loud = np.median([_size(_pose(200, 0.6, s)[0]) for s in seeds])
    # three times the noise: about nine times the variance
    assert loud > 4 * quiet, (quiet, loud)


def test_sigma_is_the_noise():
    # per-coordinate pixel noise s moves a match s off its epipolar line (Sampson distance)
    for noise in (0.2, 0.5):
        sigmas = [_pose(300, noise, s)[0].covariance.sigma_px for s in range(3)]
        assert np.median(sigmas) == pytest.approx(noise, rel=0.12), sigmas


def test_truncated_sigma_undoes_the_inlier_cut():
    rng = np.random.default_rng(3)
    r = rng.normal(0.0, 0.5, 200_000)
    kept = r[np.abs(r) < 1.0]
    rms = float(np.sqrt(np.mean(kept**2)))
    assert rms < 0.45  # the cut at two sigma hides a tenth of the spread
    assert truncated_sigma(rms, 1.0) == pytest.approx(0.5, rel=0.01)
    assert truncated_sigma(0.9, 1.0) == 1.0  # no Gaussian fits: the cut itself


def test_bounds_cover_the_true_error_on_a_seeded_set():
    covered_rot, covered_dir = [], []
    for seed in range(40):
        pose, R_gt, t_gt = _pose(200, 0.5, seed, n_outliers=40)
        c = pose.covariance
        d = rotation_error(pose.R, R_gt)
        e = direction_error(pose.t, t_gt, c.basis)
        covered_rot.append(d @ np.linalg.solve(c.cov[:3, :3], d) <= chi2.ppf(0.95, 3))
        covered_dir.append(e @ np.linalg.solve(c.cov[3:, 3:], e) <= chi2.ppf(0.95, 2))
    # a 95% bound; of 40 pairs at least 34 (85%) inside, allowing for sampling
    assert np.mean(covered_rot) >= 0.85, np.mean(covered_rot)
    assert np.mean(covered_dir) >= 0.85, np.mean(covered_dir)


def test_pose_in_a_is_positive_definite_and_follows_the_direction():
    pose, _, _ = _pose(200, 0.5, 0)
    baseline = 0.5
    C = pose_in_a_covariance(pose.covariance, baseline)
    assert np.all(np.linalg.eigvalsh(C) > 0)
    # across the baseline: baseline^2 times the direction's variance
    D = pose.covariance.direction_in_a()
    d = -pose.R.T @ pose.t
    across = np.linalg.svd(d[None])[2][1:]  # (2, 3) normal to d
    assert np.allclose(across @ C[:3, :3] @ across.T, baseline**2 * across @ D @ across.T)
    # the rotation block is the rotation's, seen from camera a
    assert np.allclose(C[3:, 3:], pose.covariance.rotation_in_a())


def test_no_covariance_without_enough_points():
    pose, _, _ = _pose(200, 0.5, 0)
    pts = np.array([[100.0, 100.0]] * 5)
    assert pose_covariance(pose.R, pose.t, pts, pts, np.eye(3), np.eye(3)) is None
