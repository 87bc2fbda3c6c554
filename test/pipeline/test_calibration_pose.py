"""Relative pose from F (E decomposition, cheirality, refinement) and calibrated stereo F."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from sepfm_ros.geometry import estimate_fundamental, normalize_fundamental
from sepfm_ros.geometry.calibrated.camera import camera_model
from sepfm_ros.geometry.calibrated.pose import (
    direction_error_deg,
    essential_from_fundamental,
    fundamental_from_pose,
    pose_from_projections,
    pose_of_b_in_a,
    relative_pose,
    rotation_error_deg,
    stereo_baseline,
    stereo_fundamental,
    stereo_pose,
)
from sepfm_ros.geometry.epipolar import fundamental_from_cameras
from sepfm_ros.geometry.synthetic import make_pair
from sepfm_ros.pipeline.pipeline import Pipeline, PipelineConfig


def _same_up_to_scale(F1: np.ndarray, F2: np.ndarray) -> float:
    a = normalize_fundamental(F1).ravel()
    b = normalize_fundamental(F2).ravel()
    return float(min(np.linalg.norm(a - b), np.linalg.norm(a + b)))


def test_pose_on_synthetic_cameras():
    errors = {False: [], True: []}
    for seed in range(6):
        pair = make_pair(n_inliers=300, n_outliers=60, noise=0.5, seed=seed)
        K_a, K_b, R_gt, t_gt = pose_from_projections(pair.P1, pair.P2)
        est = estimate_fundamental(pair.pts1, pair.pts2, pair.image_size, seed=0)
        assert est.ok
        for refine in (False, True):
            pose = relative_pose(est.F, pair.pts1, pair.pts2, K_a, K_b, est.inliers, refine=refine)
            assert pose.ok and pose.in_front > 0.95
            assert np.linalg.norm(pose.t) == pytest.approx(1.0)
            rot_err = rotation_error_deg(pose.R, R_gt)
            dir_err = direction_error_deg(pose.t, t_gt)
            assert rot_err < 0.4, (seed, refine, rot_err)
            assert dir_err < 3.0, (seed, refine, dir_err)
            errors[refine].append((rot_err, dir_err))
    raw, refined = np.mean(errors[False], axis=0), np.mean(errors[True], axis=0)
    # the Sampson refinement on the inliers improves the bare decomposition on average
    assert refined[0] < raw[0] and refined[1] < raw[1], (raw, refined)


def test_pose_decomposition_exact_and_inverse():
    pair = make_pair(n_inliers=100, noise=0.0, seed=5)
    K_a, K_b, R_gt, t_gt = pose_from_projections(pair.P1, pair.P2)
    F = fundamental_from_pose(R_gt, t_gt, K_a, K_b)
    assert _same_up_to_scale(F, pair.F) < 1e-6
    E = essential_from_fundamental(F, K_a, K_b)
    s = np.linalg.svd(E, compute_uv=False)
    assert s[0] == pytest.approx(s[1], rel=1e-6) and s[2] < 1e-6
    pose = relative_pose(F, pair.pts1, pair.pts2, K_a, K_b)
    assert rotation_error_deg(pose.R, R_gt) < 1e-4
    assert direction_error_deg(pose.t, t_gt) < 1e-3
    # b in a: (R^T, -R^T t) is the inverse, and the centre of b expressed in a's frame
    R_ba, p_ba = pose_of_b_in_a(pose.R, pose.t)
    np.testing.assert_allclose(R_ba @ pose.R, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(pose.R @ p_ba + pose.t, np.zeros(3), atol=1e-12)


def test_too_few_inliers_has_status():
    pair = make_pair(n_inliers=20, seed=0)
    n = len(pair.pts1)
    pose = relative_pose(pair.F, pair.pts1, pair.pts2, np.eye(3), np.eye(3), np.arange(n) < 3)
    assert not pose.ok and "too few" in pose.status
    with pytest.raises(ValueError, match="differ in length"):
        relative_pose(pair.F, pair.pts1, pair.pts2[:-1], np.eye(3), np.eye(3))


def _kitti_models(shared_data, frame: str):
    """CameraInfo-like models of a KITTI stereo frame: world cameras -> rig-relative P's."""
    cams = json.loads((shared_data / "cameras.json").read_text())
    P_l = np.array(cams[f"kitti_seq2/left/{frame}.png"])
    P_r = np.array(cams[f"kitti_seq2/right/{frame}.png"])
    K_a, K_b, R, t = pose_from_projections(P_l, P_r)
    assert rotation_error_deg(R, np.eye(3)) < 1e-4
    ma = camera_model(K_a, [], "", np.eye(3), K_a @ np.eye(3, 4), 1241, 376)
    P_b = K_b @ np.concatenate([np.eye(3), t[:, None]], axis=1)
    mb = camera_model(K_b, [], "", np.eye(3), P_b, 1241, 376)
    return ma, mb


def test_kitti_stereo_pose(shared_data):
    left = cv2.imread(str(shared_data / "kitti_seq2/left/000000.png"), cv2.IMREAD_GRAYSCALE)
    right = cv2.imread(str(shared_data / "kitti_seq2/right/000000.png"), cv2.IMREAD_GRAYSCALE)
    res = Pipeline(PipelineConfig()).process(left, right)
    assert res.ok
    ma, mb = _kitti_models(shared_data, "000000")
    pose = relative_pose(
        res.estimate.F, res.matches.pts_a, res.matches.pts_b, ma.K, mb.K, res.estimate.inliers
    )
    assert pose.ok and pose.in_front > 0.9
    # free stereo pose: pitch and roll are well determined; yaw trades off against a forward
    # translation on a rectified pair (about 0.8 degrees here), so it is bounded loosely
    pitch, yaw, roll = np.degrees(cv2.Rodrigues(pose.R)[0].ravel())
    assert abs(pitch) < 0.15 and abs(roll) < 0.15, (pitch, roll)
    assert pose.rotation_deg < 1.5
    # right camera: X_right = X_left - B x, so t points along -x and b sits at +x in a's frame
    assert direction_error_deg(pose.t, [-1.0, 0.0, 0.0]) < 10.0
    B = stereo_baseline(ma, mb)
    assert B == pytest.approx(0.537, abs=0.001)
    _, p_ba = pose_of_b_in_a(pose.R, pose.scaled(B).t)
    assert p_ba[0] == pytest.approx(B, rel=0.02)


def test_kitti_rectified_calibrated_f_equals_gt(shared_data):
    pairs = json.loads((shared_data / "pairs.json").read_text())
    stereo = [p for p in pairs if p["baseline"] == "stereo" and "kitti" in p["img_a"]]
    assert stereo
    for p in stereo:
        frame = p["img_a"].split("/")[-1][:-4]
        ma, mb = _kitti_models(shared_data, frame)
        F_cal = stereo_fundamental(ma.rectified(), mb.rectified())
        assert _same_up_to_scale(F_cal, np.array(p["F"])) < 1e-6
        R, t = stereo_pose(ma, mb)
        np.testing.assert_allclose(R, np.eye(3), atol=1e-9)


def test_raw_rig_with_rectification_rotations():
    K_a = np.array([[700.0, 0, 630.0], [0, 705.0, 370.0], [0, 0, 1]])
    K_b = np.array([[690.0, 0, 650.0], [0, 695.0, 355.0], [0, 0, 1]])
    D = np.array([-0.1, 0.02, 0.0, 0.0, 0.0])
    R0 = cv2.Rodrigues(np.radians([0.8, -1.5, 0.6]))[0]
    T0 = np.array([-0.12, 0.004, 0.006])
    size = (1280, 720)
    R1, R2, P1, P2 = cv2.stereoRectify(K_a, D, K_b, D, size, R0, T0.reshape(3, 1), alpha=0)[:4]
    ma = camera_model(K_a, D, "plumb_bob", R1, P1, *size)
    mb = camera_model(K_b, D, "plumb_bob", R2, P2, *size)
    R, t = stereo_pose(ma, mb)
    assert rotation_error_deg(R, R0) < 1e-6
    np.testing.assert_allclose(t, T0, atol=1e-9)
    assert stereo_baseline(ma, mb) == pytest.approx(np.linalg.norm(T0), rel=1e-9)
    F_gt = fundamental_from_cameras(
        K_a @ np.eye(3, 4), K_b @ np.concatenate([R0, T0[:, None]], axis=1)
    )
    assert _same_up_to_scale(stereo_fundamental(ma, mb), F_gt) < 1e-6
    # the rectified images' F is the horizontal-lines F (rows match)
    F_rect = stereo_fundamental(ma.rectified(), mb.rectified())
    assert _same_up_to_scale(F_rect, np.array([[0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])) < 1e-6
