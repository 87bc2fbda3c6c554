"""The DEGENSAC-style dominant-plane check (sepfm_ros/geometry/fundamental/degeneracy.py) on
synthetic planar-majority scenes: most 3D points on one plane, a few off it, many outliers.
Without the check the estimator often returns a wrong F with status "ok" (the plane fixes all
but three of F's degrees of freedom and outliers outvote the few off-plane points); with it,
such an F is either replaced by a plane-and-parallax F or flagged. Prints the counts.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from sepfm_ros.geometry import estimate_fundamental, symmetric_epipolar_distance
from sepfm_ros.geometry.epipolar import fundamental_from_cameras
from sepfm_ros.geometry.fundamental.degeneracy import (
    chance_inliers,
    parallax_models,
    plane_and_parallax,
    random_pairs,
    robust_homography,
    transfer_error,
)
from sepfm_ros.geometry.synthetic import look_at_camera

SIZE = (640, 480)
SEEDS = range(40)
WRONG_PX = 2.0  # median distance of the true off-plane points to F's epipolar lines


def _project(P: np.ndarray, X: np.ndarray) -> np.ndarray:
    x = np.c_[X, np.ones(len(X))] @ P.T
    return x[:, :2] / x[:, 2:]


def planar_majority_pair(n_plane=170, n_off=20, n_out=80, noise=0.5, seed=0):
    """Matches of a scene with ``n_plane`` points on one plane and ``n_off`` at least 0.5 m off
    it (scene 5 m across, 6 m away), plus ``n_out`` random outliers; Gaussian noise in px.

    Returns (pts1, pts2, true off-plane pts1, true off-plane pts2 (noise-free), GT F).
    """
    rng = np.random.default_rng(seed)
    w, h = SIZE
    K = np.array([[0.9 * w, 0, w / 2], [0, 0.9 * w, h / 2], [0, 0, 1.0]])
    target = np.array([0.0, 0.0, 6.0])
    c1 = rng.normal(0, 0.3, 3)
    d = rng.normal(0, 1, 3)
    d[2] *= 0.3
    c2 = c1 + d / np.linalg.norm(d)
    P1 = look_at_camera(K, c1, target + rng.normal(0, 0.2, 3))
    P2 = look_at_camera(K, c2, target + rng.normal(0, 0.2, 3))
    normal = rng.normal(0, 1, 3)
    normal[2] += 2.0
    normal /= np.linalg.norm(normal)
    a = np.cross(normal, [1.0, 0, 0])
    a /= np.linalg.norm(a)
    b = np.cross(normal, a)

    def visible(X):
        ok = np.ones(len(X), bool)
        for P in (P1, P2):
            x = _project(P, X)
            depth = np.c_[X, np.ones(len(X))] @ P[2]
            ok &= (depth > 0) & (x[:, 0] > 1) & (x[:, 0] < w - 2)
            ok &= (x[:, 1] > 1) & (x[:, 1] < h - 2)
        return ok

    def sample(m, on_plane):
        out = np.zeros((0, 3))
        while len(out) < m:
            if on_plane:
                st = rng.uniform(-2.5, 2.5, (4 * m, 2))
                X = target + st[:, :1] * a + st[:, 1:] * b
            else:
                X = target + rng.uniform(-2.5, 2.5, (4 * m, 3))
                X = X[np.abs((X - target) @ normal) > 0.5]
            out = np.concatenate([out, X[visible(X)]])
        return out[:m]

    X = np.concatenate([sample(n_plane, True), sample(n_off, False)])
    x1, x2 = _project(P1, X), _project(P2, X)
    o1 = rng.uniform([0, 0], [w - 1, h - 1], (n_out, 2))
    o2 = rng.uniform([0, 0], [w - 1, h - 1], (n_out, 2))
    pts1 = np.r_[x1 + rng.normal(0, noise, x1.shape), o1]
    pts2 = np.r_[x2 + rng.normal(0, noise, x2.shape), o2]
    return pts1, pts2, x1[n_plane:], x2[n_plane:], fundamental_from_cameras(P1, P2)


def test_parallax_model_from_exact_plane_and_two_points_is_the_true_f():
    pts1, pts2, off1, off2, F_gt = planar_majority_pair(n_out=0, noise=0.0, seed=3)
    H, _ = cv2.findHomography(pts1[:170], pts2[:170], 0)
    F = parallax_models(H, np.r_[off1[:2]], np.r_[off2[:2]], np.array([[0, 1]]))[0]
    assert np.median(symmetric_epipolar_distance(F, off1, off2)) < 1e-4
    assert np.median(symmetric_epipolar_distance(F, pts1, pts2)) < 1e-4


def test_random_pairs_are_distinct_and_uniform():
    items = np.array([3, 8, 11, 40, 41])
    pairs = random_pairs(np.random.default_rng(0), items, 20000)
    assert pairs.shape == (20000, 2) and np.isin(pairs, items).all()
    assert (pairs[:, 0] != pairs[:, 1]).all()
    _, counts = np.unique(pairs, axis=0, return_counts=True)
    assert len(counts) == 20  # every ordered pair of two different items
    assert np.abs(counts - 1000).max() < 5 * np.sqrt(1000)
    two = random_pairs(np.random.default_rng(1), np.array([5, 9]), 50)
    assert {tuple(p) for p in two} == {(5, 9), (9, 5)}


def test_chance_count_matches_random_pairs():
    rng = np.random.default_rng(0)
    pts1, pts2, _, _, F_gt = planar_majority_pair(n_out=0, noise=0.0, seed=1)
    exact = int(np.count_nonzero(symmetric_epipolar_distance(F_gt, pts1, pts2) < 1.0))
    chance = chance_inliers(F_gt, pts1, pts2, 1.0, rng)
    assert exact == len(pts1) and chance < 0.1 * len(pts1)


@pytest.mark.parametrize(("n_off", "n_out"), [(20, 80), (10, 30)])
def test_plane_check_removes_confident_wrong_f(n_off, n_out):
    counts = {"without": {"wrong_ok": 0, "right_ok": 0}, "with": {"wrong_ok": 0, "right_ok": 0}}
    for seed in SEEDS:
        pts1, pts2, off1, off2, _ = planar_majority_pair(n_off=n_off, n_out=n_out, seed=seed)
        for name, check in (("without", False), ("with", True)):
            est = estimate_fundamental(pts1, pts2, SIZE, seed=seed, plane_check=check)
            assert est.F is not None
            err = float(np.median(symmetric_epipolar_distance(est.F, off1, off2)))
            if est.status == "ok":
                counts[name]["wrong_ok" if err > WRONG_PX else "right_ok"] += 1
            else:
                assert est.status.startswith("degenerate"), est.status
    print(f"\n[robustness] plane check, {n_off} off-plane, {n_out} outliers, 170 on the plane, "
          f"{len(SEEDS)} scenes: {counts}")  # fmt: skip
    assert counts["without"]["wrong_ok"] >= 8  # the scene is hard without the check
    # with the check, no scene may end on a wrong F reported "ok"
    assert counts["with"]["wrong_ok"] == 0, counts
    # the check may flag a few right answers with little off-plane support as degenerate; over
    # estimator seeds (same scenes) the loss varied from 0 to 3 of 40 scenes, so allow 4
    assert counts["with"]["right_ok"] >= counts["without"]["right_ok"] - 4


def test_plane_check_keeps_general_scenes():
    from sepfm_ros.geometry.synthetic import make_pair

    for seed in range(10):
        pair = make_pair(n_inliers=150, n_outliers=60, noise=0.5, seed=seed)
        est = estimate_fundamental(pair.pts1, pair.pts2, pair.image_size, seed=seed)
        assert est.status == "ok", est.status
        check = plane_and_parallax(est.F, pair.pts1, pair.pts2, 1.0, np.random.default_rng(seed))
        assert not check.replaced and check.reason is None


def test_plane_check_accepts_without_candidates_only_an_f_with_ample_off_plane_support():
    """``accepted`` (F kept untried: its off-plane excess is at least ``accept_factor`` times the
    flagging bar) holds for the true F with 60 off-plane matches, not with 10, and an accepted
    F tried no plane-and-parallax candidates; the estimator then skips its wider search for a
    shifted plane copy."""
    for n_off, expected in ((60, True), (10, False)):
        pts1, pts2, _, _, F_gt = planar_majority_pair(n_off=n_off, n_out=40, seed=2)
        check = plane_and_parallax(F_gt, pts1, pts2, 1.0, np.random.default_rng(0))
        assert check.planar
        assert check.accepted is expected, (n_off, check)
        if expected:
            assert check.candidates == 0 and not check.replaced and check.reason is None
        else:
            assert check.candidates > 0


@pytest.mark.parametrize("method", ["sep5", "ransac7"])
def test_matches_along_one_line_are_flagged(method):
    # ORB matches of a 3 px high textured row and the same row 6 px to the right (the live
    # robustness test's "matches_on_one_line"): nearly every 4-point sample is degenerate for a
    # homography, so the plane check alone can miss it; no exception, and an F carries a
    # "degenerate" status
    from sepfm_ros.pipeline.pipeline import Pipeline, PipelineConfig

    rng = np.random.default_rng(5)
    row = np.full((240, 320), 90, np.uint8)
    row[118:121, 20:-20] = rng.integers(0, 256, (3, 280))
    result = Pipeline(PipelineConfig(method=method)).process(row, np.roll(row, 6, axis=1))
    est = result.estimate
    assert len(result.matches) >= 50
    assert est.F is None or est.status.startswith("degenerate"), est.status
    assert est.status != "ok"
    if est.F is not None:  # the band is named, not only the plane that holds it
        assert "lie along one line" in est.status, est.status


@pytest.mark.parametrize("seed", [4, 18, 47])
def test_plane_check_keeps_a_right_f_whose_off_plane_support_is_small(seed):
    # 10 off-plane points: the estimator without the check finds the right F, and a
    # plane-and-parallax candidate that fits the plane's matches closer (a lower MSAC cost) but
    # keeps only 1-2 of the off-plane ones must not replace it (it would then be flagged as a
    # dominant plane and the right F lost)
    pts1, pts2, off1, off2, _ = planar_majority_pair(n_off=10, n_out=30, seed=seed)
    # the line search's F: the escape would hand seeds 4 and 47 to standard RANSAC, which
    # without the plane check stops on the plane (test_escape.py: with it, sep4 retries)
    est = estimate_fundamental(
        pts1, pts2, SIZE, seed=seed, plane_check=False, line_search_escape=False
    )
    assert np.median(symmetric_epipolar_distance(est.F, off1, off2)) < 1.0
    check = plane_and_parallax(est.F, pts1, pts2, 1.0, np.random.default_rng(seed))
    assert check.planar and check.candidates > 0  # challenged: its support is not far above chance
    assert not check.replaced and check.reason is None
    assert np.median(symmetric_epipolar_distance(check.F, off1, off2)) < 1.0


def test_robust_homography_finds_the_plane_and_follows_its_seed():
    """The shared RHO search: on 60 % plane matches among random ones it returns a homography
    that holds at least that share within the tolerance; the same seed gives the same H, and a
    set with no plane at that share gives a homography holding far less of it or None."""
    rng = np.random.default_rng(3)
    H_true = np.array([[1.05, 0.02, 12.0], [-0.01, 0.98, -7.0], [1e-5, -2e-5, 1.0]])
    p1 = rng.uniform(0, 600, (200, 2))
    p2 = cv2.perspectiveTransform(p1[None], H_true)[0] + rng.normal(0, 0.3, (200, 2))
    p2[120:] = rng.uniform(0, 600, (80, 2))  # 40 % random matches
    H = robust_homography(p1, p2, 2.0, 0.5, seed=11, max_trials=500)
    assert H is not None
    on = transfer_error(H, p1, p2) < 2.0
    assert np.count_nonzero(on) >= 0.6 * 200 - 5
    assert np.count_nonzero(on[120:]) <= 3  # the random matches stay off it
    again = robust_homography(p1, p2, 2.0, 0.5, seed=11, max_trials=500)
    np.testing.assert_array_equal(H, again)
    noise = rng.uniform(0, 600, (200, 2))
    H_none = robust_homography(p1, noise, 2.0, 0.5, seed=11, max_trials=500)
    if H_none is not None:
        assert np.count_nonzero(transfer_error(H_none, p1, noise) < 2.0) < 0.2 * 200


def test_plane_check_on_prepared_matches_is_the_same_check():
    """``data`` (the matches prepared by the caller) only saves building them again: the same
    check, candidates, model and transfer errors, from the same draws, as without it."""
    from sepfm_ros.geometry.fundamental.correspondences import Correspondences

    tried = 0
    for seed in range(8):
        pts1, pts2, *_ = planar_majority_pair(n_off=12, n_out=120, seed=seed)
        F = estimate_fundamental(pts1, pts2, SIZE, seed=seed, plane_check=False).F
        data = Correspondences.from_pixels(pts1, pts2)
        a = plane_and_parallax(F, pts1, pts2, 1.0, np.random.default_rng(seed))
        b = plane_and_parallax(F, pts1, pts2, 1.0, np.random.default_rng(seed), data=data)
        tried += a.candidates > 0  # the candidates' path, where data is used
        assert np.array_equal(a.F, b.F) and np.array_equal(a.transfer, b.transfer)
        assert (a.replaced, a.plane_inliers, a.off_plane_inliers, a.candidates, a.reason) == (
            b.replaced, b.plane_inliers, b.off_plane_inliers, b.candidates, b.reason,
        )  # fmt: skip
        assert np.array_equal(a.transfer, transfer_error(a.H, pts1, pts2))
    assert tried >= 2
