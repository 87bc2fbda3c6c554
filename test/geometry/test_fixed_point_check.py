"""The fixed-point check of the separable stage 2 (option ``fixed_point_check``): an arm whose
fixed line correspondences are not all inliers of the best model cannot draw an all-inlier sample
for it, so its samples stop counting toward F(k, r) and the arm is dropped."""

from __future__ import annotations

import numpy as np
import pytest
from ground_truth import manifest_pair

from sepfm_ros.evaluation.metrics import run_metrics
from sepfm_ros.geometry import EstimatorOptions, estimate_fundamental
from sepfm_ros.geometry.epipolar import symmetric_epipolar_distance
from sepfm_ros.geometry.fundamental.correspondences import Correspondences
from sepfm_ros.geometry.fundamental.problem import FundamentalProblem
from sepfm_ros.geometry.robust.loop import run_ransac
from sepfm_ros.geometry.robust.options import SamplingOptions
from sepfm_ros.geometry.synthetic import make_pair


def _scene(seed: int = 3):
    """A synthetic pair, its matches, three true matches as the fixed points (spread out) and
    the pool of the others."""
    pair = make_pair(n_inliers=200, n_outliers=80, n_lines=0, noise=0.3, seed=seed)
    data = Correspondences.from_pixels(pair.pts1, pair.pts2)
    true = np.flatnonzero(pair.is_inlier)
    fixed = true[np.argsort(pair.pts1[true, 0])[[0, len(true) // 2, -1]]]
    pool = np.setdiff1d(np.arange(len(pair.pts1)), fixed)
    return pair, data, fixed, pool


def _shifted(pair, fixed, i: int, px: float):
    """Fixed points with point ``i`` moved ``px`` pixels across its GT epipolar line in image 2."""
    f1, f2 = pair.pts1[fixed].copy(), pair.pts2[fixed].copy()
    line = pair.F @ np.append(f1[i], 1.0)
    f2[i] += px * line[:2] / np.hypot(line[0], line[1])
    return f1, f2


def test_fixed_inliers_tells_a_wrong_fixed_point_from_noise():
    pair, data, fixed, pool = _scene()
    f1, f2 = pair.pts1[fixed], pair.pts2[fixed]
    assert symmetric_epipolar_distance(pair.F, f1, f2).max() < 1.5
    arm = FundamentalProblem(data, "seven", 1.0, fixed1=f1, fixed2=f2, pool=pool, fixed_tol=1.5)
    assert arm.fixed_inliers(pair.F)
    w1, w2 = _shifted(pair, fixed, 2, 6.0)
    wrong = FundamentalProblem(data, "seven", 1.0, fixed1=w1, fixed2=w2, pool=pool, fixed_tol=1.5)
    assert not wrong.fixed_inliers(pair.F)
    # without the check (fixed_tol 0) every model passes
    unchecked = FundamentalProblem(data, "seven", 1.0, fixed1=w1, fixed2=w2, pool=pool)
    assert unchecked.fixed_inliers(pair.F)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_an_arm_with_a_wrong_fixed_point_does_not_converge_and_is_dropped(seed):
    pair, data, fixed, pool = _scene()
    sampling = EstimatorOptions().sampling()
    w1, w2 = _shifted(pair, fixed, 2, 6.0)
    results = {}
    for tol in (1.5, 0.0):
        arm = FundamentalProblem(data, "seven", 1.0, fixed1=w1, fixed2=w2, pool=pool, fixed_tol=tol)
        results[tol] = run_ransac(
            [arm], np.random.default_rng(seed), max_samples=2000, sampling=sampling
        )
    # the wrong fixed point keeps every model of the arm off the true F: without the check the
    # loop stops on its best one as if converged; with it the arm is dropped, unconverged
    # (the separable estimator then runs its fallback), after far fewer samples than the cap
    assert results[0.0].converged and results[0.0].dropped == []
    checked = results[1.5]
    assert not checked.converged and checked.dropped == [0]
    assert sum(checked.samples) < 2000
    # the control: the true fixed points converge with the check on, and the arm stays
    arm = FundamentalProblem(
        data, "seven", 1.0, fixed1=pair.pts1[fixed], fixed2=pair.pts2[fixed], pool=pool,
        fixed_tol=1.5,
    )  # fmt: skip
    good = run_ransac([arm], np.random.default_rng(seed), max_samples=2000, sampling=sampling)
    assert good.converged and good.dropped == []
    d = symmetric_epipolar_distance(good.model, pair.pts1, pair.pts2)
    assert np.median(d[pair.is_inlier]) < 0.5


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_an_inconsistent_arm_is_kept_while_a_search_without_fixed_points_cannot_finish(seed):
    # at the best model's inlier ratio (about 0.7) F(7, r) is about 50 samples: with a budget of
    # 30 a search without fixed points could not confirm the best model, which may then still
    # be a chance one, so the arm is not dropped at once (it spends the budget, unconverged);
    # with 2000 it is dropped within a few samples
    pair, data, fixed, pool = _scene()
    w1, w2 = _shifted(pair, fixed, 2, 6.0)
    sampling = EstimatorOptions().sampling()
    out = {}
    for cap in (30, 2000):
        arm = FundamentalProblem(data, "seven", 1.0, fixed1=w1, fixed2=w2, pool=pool, fixed_tol=1.5)
        rng = np.random.default_rng(seed)
        out[cap] = run_ransac([arm], rng, max_samples=cap, sampling=sampling)
    assert out[30].dropped == [] and out[30].samples == [30] and not out[30].converged
    assert out[2000].dropped == [0] and out[2000].samples[0] <= 40


def test_check_is_inert_for_arms_without_fixed_points():
    pair, data, _, _ = _scene()
    arm = FundamentalProblem(data, "seven", 1.0, fixed_tol=1.5)
    assert arm.fixed_inliers(np.eye(3))
    result = run_ransac([arm], np.random.default_rng(0), sampling=SamplingOptions(prosac=True))
    assert result.converged and result.dropped == []


def test_option_is_validated():
    with pytest.raises(ValueError, match="fixed_point_check"):
        EstimatorOptions(fixed_point_check=-1.0)


def test_kitti_pair_whose_extreme_line_match_is_wrong(shared_data):
    # kitti_seq2 left 000006 -> 000007 at SIFT ratio 0.95: the raw triple of the first line pair
    # holds a match 8.6 px from the GT F (an H_e inlier at the end of the line: near the line,
    # wrong across it). Without the check sep4 stopped on a basin of about 390 inliers (F-score
    # 0.80-0.83) on seeds 1-3; the 7-point baseline finds about 515 every time.
    _, m, pos = manifest_pair(shared_data, "kitti_seq2/left/000006~left/000007", 0.95)
    # Inner sampling of the final model (on by default) also leaves that basin; it is off here
    # so the check is measured alone, and then on without the check. The escape is off: the
    # check is stage 2's, and on some seeds the escape skips the line search on this pair.
    f_score = {}
    for check, inner in ((1.5, 0), (0.0, 0), (0.0, 20)):
        for seed in range(4):
            est = estimate_fundamental(
                m.pts_a, m.pts_b, m.size_a, m.size_b, threshold=1.0, seed=seed,
                fixed_point_check=check, inner_samples=inner, line_search_escape=False,
            )  # fmt: skip
            assert est.status == "ok"
            f_score[check, inner, seed] = run_metrics(est.F, m.pts_a, m.pts_b, pos, 1.0).f_score
    assert all(f_score[1.5, 0, s] > 0.95 for s in range(4)), f_score
    assert sum(f_score[0.0, 0, s] < 0.9 for s in range(4)) >= 2, f_score  # the trap is real
    assert all(f_score[0.0, 20, s] > 0.95 for s in range(4)), f_score
