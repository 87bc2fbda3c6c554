"""Uncalibrated rectification (sepfm_ros/pipeline/rectification.py): a synthetic rig and a real
stereo pair whose right image is rotated by a known angle come out with a median vertical
disparity under 0.5 px from the estimator's own F; each failure mode gives its error kind."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from sepfm_ros.geometry import estimate_fundamental, symmetric_epipolar_distance
from sepfm_ros.pipeline.pipeline import Pipeline
from sepfm_ros.pipeline.rectification import (
    RectificationError,
    apply_homography,
    coverage,
    epipoles,
    rectify_uncalibrated,
    vertical_disparity,
)

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
import bench_rectify  # noqa: E402

SIZE = (640, 480)
TARGET_PX = 0.5
IDENTITY = np.eye(3)


def _skew(t: np.ndarray) -> np.ndarray:
    return np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])


def synthetic_rig(
    baseline: np.ndarray, deg: float, noise_px: float = 0.0, seed: int = 0, n: int = 300
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Camera a at the origin, camera b at ``-R^T baseline``-ish: x_b = K (R X + t), R by
    ``deg`` about (1, 1, 1). Returns (F, pts_a (n, 2), pts_b (n, 2)), noise on the points."""
    rng = np.random.default_rng(seed)
    w, h = SIZE
    K = np.array([[500.0, 0, w / 2], [0, 500.0, h / 2], [0, 0, 1]])
    X = np.c_[rng.uniform(-3, 3, n), rng.uniform(-2, 2, n), rng.uniform(5, 15, n)]
    R = bench_rectify.rotation(deg)
    t = np.asarray(baseline, dtype=np.float64)
    xa, xb = (K @ X.T).T, (K @ (R @ X.T + t[:, None])).T
    pts_a = xa[:, :2] / xa[:, 2:] + rng.normal(0, noise_px, (n, 2))
    pts_b = xb[:, :2] / xb[:, 2:] + rng.normal(0, noise_px, (n, 2))
    Ki = np.linalg.inv(K)
    return Ki.T @ _skew(t) @ R @ Ki, pts_a, pts_b


@pytest.mark.parametrize("side", [1.0, -1.0], ids=["b right of a", "b left of a"])
def test_synthetic_rig_rectified_from_estimated_F(side):
    _, pts_a, pts_b = synthetic_rig(np.array([-0.5 * side, 0.02, 0.01]), 3.0, noise_px=0.3)
    before = np.median(vertical_disparity(IDENTITY, IDENTITY, pts_a, pts_b))
    est = estimate_fundamental(pts_a, pts_b, SIZE, SIZE, threshold=1.0, seed=0)
    assert est.ok, est.status
    inl = est.inliers
    rect = rectify_uncalibrated(est.F, pts_a[inl], pts_b[inl], SIZE, SIZE)
    after = np.median(vertical_disparity(rect.H_a, rect.H_b, pts_a, pts_b))
    assert before > 5.0
    assert after < TARGET_PX
    # the right way up, not mirrored, at about the native scale, and framed in the output
    centre = apply_homography(rect.H_a, np.array([[320.0, 240.0], [330.0, 240.0], [320.0, 250.0]]))
    assert centre[1, 0] - centre[0, 0] == pytest.approx(10.0, rel=0.1)
    assert centre[2, 1] - centre[0, 1] == pytest.approx(10.0, rel=0.1)
    for H, pts in ((rect.H_a, pts_a), (rect.H_b, pts_b)):
        p = apply_homography(H, pts)
        inside = (p >= 0).all(axis=1) & (p < np.array(rect.size)).all(axis=1)
        assert inside.mean() > 0.9
    assert rect.size == SIZE and rect.inliers == int(inl.sum())


def test_exact_F_rectifies_exactly():
    F, pts_a, pts_b = synthetic_rig(np.array([-0.5, 0.05, 0.0]), 1.0)
    rect = rectify_uncalibrated(F, pts_a, pts_b, SIZE, SIZE)
    assert vertical_disparity(rect.H_a, rect.H_b, pts_a, pts_b).max() < 1e-6


def test_warp_keeps_dtype_and_channels_and_checks_sizes():
    F, pts_a, pts_b = synthetic_rig(np.array([-0.5, 0.05, 0.0]), 1.0)
    rect = rectify_uncalibrated(F, pts_a, pts_b, SIZE, SIZE, out_size=(400, 300))
    colour = np.full((480, 640, 3), 200, np.uint8)
    out_a, out_b = rect.warp(colour, colour[:, :, 0])
    assert out_a.shape == (300, 400, 3) and out_b.shape == (300, 400)
    assert out_a.dtype == np.uint8 and out_a.max() == 200
    with pytest.raises(ValueError, match="rectification is for"):
        rect.warp(colour[:240], colour)


@pytest.mark.parametrize(
    ("case", "kind"),
    [
        ("few", "too_few_inliers"),
        ("rank1", "degenerate_f"),
        ("nan", "degenerate_f"),
        ("forward", "epipole_inside"),
        ("near", "distorted"),
        ("shape", "bad_input"),
        ("vertical", "vertical_disparity"),
    ],
)
def test_failure_modes_raise_their_kind(case, kind):
    F, pts_a, pts_b = synthetic_rig(np.array([-0.5, 0.05, 0.0]), 1.0)
    kwargs = {}
    if case == "few":
        pts_a, pts_b = pts_a[:10], pts_b[:10]
    elif case == "rank1":
        F = np.outer([1.0, 2.0, 3.0], [0.5, -1.0, 2.0])
    elif case == "nan":
        F = F.copy()
        F[0, 0] = np.nan
    elif case == "forward":  # camera b moves toward the scene: epipole near the centre
        F, pts_a, pts_b = synthetic_rig(np.array([0.05, 0.02, -1.0]), 0.5)
    elif case == "near":  # mostly sideways, a bit forward: epipole just outside image a
        F, pts_a, pts_b = synthetic_rig(np.array([-1.0, 0.0, -1.3]), 0.0)  # at (705, 240)
        e_a = epipoles(F)[0]
        assert not 0 <= e_a[0] / e_a[2] < SIZE[0]  # outside, so the epipole check passes
    elif case == "shape":
        pts_b = pts_b[:, :1]
    elif case == "vertical":  # a wrong F: the rows do not agree
        pts_b = pts_b + np.array([0.0, 3.0]) * np.sign(pts_b[:, :1] - 320)
        kwargs["max_vertical_px"] = 1.0
    with pytest.raises(RectificationError) as info:
        rectify_uncalibrated(F, pts_a, pts_b, SIZE, SIZE, **kwargs)
    assert info.value.kind == kind
    assert str(info.value)


def test_real_stereo_pair_with_rotated_right_image(shared_data):
    """KITTI stereo, right image rotated 2 degrees: the pipeline's F rectifies its ground-truth
    matches to under 0.5 px, from several pixels before."""
    pairs = json.loads((shared_data / "pairs.json").read_text())
    cams = json.loads((shared_data / "cameras.json").read_text())
    entry = next(p for p in pairs if p["baseline"] == "stereo" and p["scene"] == "kitti_seq2")
    case = bench_rectify.rotated_case(entry, cams, 2.0)
    result = Pipeline(bench_rectify.CONFIG).process(case.image_a, case.image_b)
    assert result.ok, result.estimate.status
    m, inl = result.matches, result.estimate.inliers
    gt = symmetric_epipolar_distance(case.F, m.pts_a, m.pts_b) < 1.0
    assert gt.sum() > 100
    rect = rectify_uncalibrated(
        result.estimate.F, m.pts_a[inl], m.pts_b[inl], result.size_a, result.size_b
    )
    before = np.median(vertical_disparity(IDENTITY, IDENTITY, m.pts_a[gt], m.pts_b[gt]))
    after = np.median(vertical_disparity(rect.H_a, rect.H_b, m.pts_a[gt], m.pts_b[gt]))
    assert before > 5.0
    assert after < TARGET_PX
    out_a, out_b = rect.warp(case.image_a, case.image_b)
    assert out_a.shape == case.image_a.shape
    # most of the rectified left image is picture, not border
    assert (out_a > 0).mean() > 0.7 and (out_b > 0).mean() > 0.6


def test_rotated_case_matches_its_ground_truth(shared_data):
    """The benchmark's rotated pair: the warped right image agrees with its F (the GT inlier
    count is about that of the pair before rotation)."""
    pairs = json.loads((shared_data / "pairs.json").read_text())
    cams = json.loads((shared_data / "cameras.json").read_text())
    entry = next(p for p in pairs if p["baseline"] == "stereo" and p["scene"] == "tsukuba")
    straight = bench_rectify.rotated_case(entry, cams, 0.0)
    rotated = bench_rectify.rotated_case(entry, cams, 3.0)
    sift = cv2.SIFT_create()

    def gt_matches(case: bench_rectify.Case) -> int:
        ka, da = sift.detectAndCompute(case.image_a, None)
        kb, db = sift.detectAndCompute(case.image_b, None)
        good = [
            m for m, n in cv2.BFMatcher().knnMatch(da, db, k=2) if m.distance < 0.8 * n.distance
        ]
        pa = np.array([ka[m.queryIdx].pt for m in good])
        pb = np.array([kb[m.trainIdx].pt for m in good])
        return int((symmetric_epipolar_distance(case.F, pa, pb) < 1.0).sum())

    assert gt_matches(rotated) > 0.7 * gt_matches(straight) > 50


def test_strided_point_arrays_are_read_as_points():
    """Columns of one (N, 4) array (as a node reads a match list) are views with a row stride
    of 4 values: OpenCV would read them as stored."""
    F, pts_a, pts_b = synthetic_rig(np.array([-0.5, 0.05, 0.0]), 1.0)
    rows = np.c_[pts_a, pts_b]
    rect = rectify_uncalibrated(F, rows[:, :2], rows[:, 2:], SIZE, SIZE)
    assert vertical_disparity(rect.H_a, rect.H_b, pts_a, pts_b).max() < 1e-6


def test_coverage_of_the_output_and_of_the_image():
    F, pts_a, pts_b = synthetic_rig(np.array([-0.5, 0.05, 0.0]), 1.0)
    rect = rectify_uncalibrated(F, pts_a, pts_b, SIZE, SIZE)
    for H in (rect.H_a, rect.H_b):
        covered, kept = coverage(H, SIZE, rect.size)
        assert covered > 0.9 and kept > 0.9
    half = np.diag([0.5, 0.5, 1.0])  # the image shrunk into the top-left quarter
    assert coverage(half, SIZE, SIZE) == pytest.approx((0.25, 1.0), abs=0.01)
    assert coverage(np.linalg.inv(half), SIZE, SIZE)[1] == pytest.approx(0.25, abs=0.03)
