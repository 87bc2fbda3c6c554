"""Evaluation metrics against values computed by hand on tiny cases."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sepfm_ros.evaluation import metrics
from sepfm_ros.evaluation.manifest import PairDataError, parse_fundamental

# Rectified stereo: x_b^T F x_a = v_a - v_b, epipolar lines are the rows, so the symmetric
# epipolar distance of a match is |v_b - v_a|.
F_RECT = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
# The same with the rows of image b shifted down by 0.5 px: distance |v_b - v_a - 0.5|.
F_SHIFT = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.5]])


def _matches(dv):
    """Matches (N, 2) x2 with v_b - v_a = dv and arbitrary columns."""
    dv = np.asarray(dv, dtype=np.float64)
    n = dv.size
    pts_a = np.stack([np.linspace(10, 300, n), np.linspace(20, 200, n)], axis=1)
    pts_b = pts_a + np.stack([np.full(n, 7.0), dv], axis=1)
    return pts_a, pts_b


def test_f_score_of_a_known_mask():
    pred = np.array([1, 1, 0, 0, 1], bool)
    truth = np.array([1, 0, 1, 0, 1], bool)
    # tp = 2, predicted 3, true 3 -> precision = recall = F = 2/3
    p, r, f = metrics.f_score(pred, truth)
    assert (p, r) == pytest.approx((2 / 3, 2 / 3))
    assert f == pytest.approx(2 / 3)
    # precision 1/1, recall 1/3 -> F = 2 * 1 * 1/3 / (4/3) = 0.5
    assert metrics.f_score(np.array([1, 0, 0, 0, 0], bool), truth)[2] == pytest.approx(0.5)
    assert metrics.f_score(np.zeros(5, bool), truth) == (0.0, 0.0, 0.0)


def test_epipolar_distance_of_a_known_point_and_line():
    pts_a, pts_b = np.array([[10.0, 5.0]]), np.array([[40.0, 8.0]])
    # the epipolar line of x_a in image b is v = 5, x_b is 3 px below it; same in image a
    assert metrics.symmetric_epipolar_distance(F_RECT, pts_a, pts_b)[0] == pytest.approx(3.0)
    pos = metrics.positives(F_RECT, *_matches([0.0, 0.5, -0.99, 1.0, 1.5]))
    assert pos.tolist() == [True, True, True, False, False]


def test_run_metrics_by_hand():
    pts_a, pts_b = _matches([0.0, 0.3, 0.9, 1.2, 5.0, -0.8])
    positive = metrics.positives(F_RECT, pts_a, pts_b)
    assert positive.tolist() == [True, True, True, False, False, True]
    m = metrics.run_metrics(F_SHIFT, pts_a, pts_b, positive, threshold=1.0)
    # distances under F_SHIFT: 0.5, 0.2, 0.4, 0.7, 4.5, 1.3 -> inliers 0..3, tp = 3
    assert (m.n_matches, m.n_positives, m.n_inliers, m.true_positives) == (6, 4, 4, 3)
    assert m.pct_inliers == pytest.approx(100 * 4 / 6)
    assert (m.precision, m.recall, m.f_score) == pytest.approx((0.75, 0.75, 0.75))
    # positives 0, 1, 2, 5 under F_SHIFT: 0.5, 0.2, 0.4, 1.3
    assert m.mean_error == pytest.approx(0.6)
    assert m.median_error == pytest.approx(0.45)
    assert not m.evaluable and not m.failed  # 4 positives < 20: not evaluable
    assert m.succeeded  # median 0.45 px < 1 px, not failed

    none = metrics.run_metrics(None, pts_a, pts_b, positive, threshold=1.0)
    assert none.n_inliers == 0 and none.f_score == 0.0
    assert math.isnan(none.mean_error) and math.isnan(none.median_error)
    assert not none.succeeded


@pytest.mark.parametrize(("recovered", "failed"), [(19, True), (20, False)])
def test_failure_rule_twenty_positives(recovered, failed):
    # 25 positives; those with dv = -0.7 are positives but outside F_SHIFT's 1 px threshold
    dv = [0.0] * recovered + [-0.7] * (25 - recovered) + [8.0] * 10
    pts_a, pts_b = _matches(dv)
    positive = metrics.positives(F_RECT, pts_a, pts_b)
    m = metrics.run_metrics(F_SHIFT, pts_a, pts_b, positive, threshold=1.0)
    assert m.n_positives == 25 and m.true_positives == recovered
    assert m.evaluable and m.failed is failed
    assert m.succeeded is not failed  # median error 0.5 px: success follows the failure rule


def _run(pair, f, med, failed=False, hyp=None, ms=1.0, evaluable=True, has_model=True):
    return {
        "pair": pair,
        "f_score": f,
        "pct_inliers": 50.0,
        "mean_error": med,
        "median_error": med,
        "evaluable": evaluable,
        "failed": failed,
        "has_model": has_model,
        "hypotheses": hyp,
        "stage1_hypotheses": None,
        "stage2_hypotheses": None,
        "ms": ms,
    }


def test_summarize_by_hand():
    runs = [
        _run("a", 0.5, 0.2, hyp=10, ms=2.0),
        _run("b", 1.0, float("nan"), failed=True, hyp=30, ms=4.0, has_model=False),
        _run("c", 0.0, 0.6, hyp=20, evaluable=False, ms=6.0),
    ]
    s = metrics.summarize("m", runs)
    assert s.runs == 3 and s.pairs == 3
    assert s.f_score_mean == pytest.approx(0.5)
    assert s.f_score_std == pytest.approx(math.sqrt((0.25 + 0.25 + 0) / 3))
    assert s.mean_error == pytest.approx(0.4)  # NaN left out
    assert s.median_error == pytest.approx(0.4)
    assert s.failure_pct == pytest.approx(50.0)  # 1 of the 2 evaluable runs
    assert s.no_model == 1
    assert s.hypotheses == pytest.approx(20.0) and s.stage1_hypotheses is None
    assert s.ms_mean == pytest.approx(4.0)


def test_wilson_interval_and_sign_test():
    lo, hi = metrics.wilson_interval(8, 10)
    assert (lo, hi) == pytest.approx((0.4902, 0.9433), abs=1e-4)
    assert metrics.sign_test_p(9, 1) == pytest.approx(2 * 11 / 1024)
    assert metrics.sign_test_p(5, 5) == 1.0
    assert all(math.isnan(x) for x in metrics.wilson_interval(0, 0))


def test_paired_comparison_counts_and_direction():
    m = {"a": 0.9, "b": 0.8, "c": 0.5, "d": 0.7, "e": float("nan")}
    b = {"a": 0.8, "b": 0.8, "c": 0.6, "d": 0.6, "e": 0.1}
    c = metrics.paired_comparison("m", "base", "f_score", m, b, higher_is_better=True)
    assert (c.pairs, c.wins, c.losses, c.ties) == (4, 2, 1, 1)
    assert c.win_fraction == pytest.approx(2 / 3)
    assert c.mean_diff == pytest.approx(0.025)
    assert c.diff_ci[0] <= c.mean_diff <= c.diff_ci[1]
    lower = metrics.paired_comparison("m", "base", "err", m, b, higher_is_better=False)
    assert (lower.wins, lower.losses) == (1, 2)


def test_line_homography_error_by_hand():
    # line_a: u = 10, line_b: u = 20; rectified F: epipolar lines are rows
    line_a, line_b = np.array([1.0, 0.0, -10.0]), np.array([1.0, 0.0, -20.0])
    pts_a = np.array([[10.4, 7.0], [10.0, 7.0], [9.0, 2.0]])
    pts_b = np.array([[20.2, 7.3], [21.0, 8.0], [20.0, 2.0]])
    # projections (10, 7) / (20, 7.3): row 7 meets u = 20 at (20, 7) -> 0.3; row 7.3 meets
    # u = 10 at (10, 7.3) -> 0.3; mean 0.3. Second: 1.0 both ways. Third: exact.
    e = metrics.line_homography_error(F_RECT, line_a, line_b, pts_a, pts_b)
    assert e == pytest.approx([0.3, 1.0, 0.0])
    # a line parallel to the epipolar lines has no intersection
    row = np.array([0.0, 1.0, -7.0])
    assert np.isinf(metrics.line_homography_error(F_RECT, row, row, pts_a, pts_b)).all()
    # projection onto a line of a non-unit normal
    proj = metrics.project_to_line(np.array([0.0, 2.0, -4.0]), np.array([[3.0, 5.0]]))
    assert proj.ravel() == pytest.approx([3.0, 2.0])


@pytest.mark.parametrize(
    ("F", "message"),
    [
        ([[1, 2, 3], [4, 5, 6]], "expected 3x3"),
        ([[1, 0, 0], [0, 1, 0], [0, 0, "x"]], "not a 3x3 array of numbers"),
        ([[1, 0, 0], [0, 1, 0], [0, 0, float("nan")]], "NaN"),
        (np.zeros((3, 3)).tolist(), "all zeros"),
        (np.eye(3).tolist(), "not rank 2"),
    ],
)
def test_malformed_fundamental_is_named(F, message):
    with pytest.raises(PairDataError, match=message):
        parse_fundamental(F)


def test_valid_fundamental_is_normalised():
    F = parse_fundamental((3 * F_RECT).tolist())
    assert np.linalg.norm(F) == pytest.approx(1.0)
