"""The oriented epipolar constraint (solvers/orientation.py) on minimal samples' models."""

from __future__ import annotations

import numpy as np
import pytest

from sepfm_ros.geometry import estimate_fundamental
from sepfm_ros.geometry.epipolar import symmetric_epipolar_distance
from sepfm_ros.geometry.fundamental.correspondences import Correspondences
from sepfm_ros.geometry.fundamental.problem import FundamentalProblem
from sepfm_ros.geometry.robust.samplers import draw_samples
from sepfm_ros.geometry.solvers import seven_point
from sepfm_ros.geometry.solvers.orientation import left_epipole, oriented_consistent
from sepfm_ros.geometry.synthetic import make_pair


def _epipole2(F: np.ndarray) -> np.ndarray:
    e = np.empty(3)
    assert left_epipole(np.ascontiguousarray(F), e)
    return e


def _reflect_through_epipole(F: np.ndarray, x2: np.ndarray) -> np.ndarray:
    """x2 (2,) mirrored through the epipole of image 2: on the same epipolar line (the epipolar
    constraint still holds exactly) but on the other side of the epipole (orientation flips)."""
    e = _epipole2(F)
    return 2.0 * e[:2] / e[2] - x2


def test_left_epipole_is_the_left_null_vector():
    for seed in range(5):
        F = make_pair(n_inliers=20, seed=seed).F
        e = _epipole2(F)
        assert np.linalg.norm(e @ F) < 1e-12 * np.linalg.norm(e) * np.linalg.norm(F)
    assert not left_epipole(np.zeros((3, 3)), np.empty(3))


@pytest.mark.parametrize("seed", range(6))
def test_true_matches_are_consistent_under_any_sign_and_normalisation(seed):
    sp = make_pair(n_inliers=80, n_outliers=0, n_lines=2, noise=0.0, seed=seed)
    F = np.ascontiguousarray(sp.F)
    assert oriented_consistent(F, sp.pts1, sp.pts2)
    assert oriented_consistent(-F, sp.pts1, sp.pts2)
    data = Correspondences.from_pixels(sp.pts1, sp.pts2)
    F_n = np.linalg.inv(data.T2).T @ F @ np.linalg.inv(data.T1)
    assert oriented_consistent(np.ascontiguousarray(F_n), data.x1, data.x2)


@pytest.mark.parametrize("seed", range(6))
def test_a_match_mirrored_through_the_epipole_breaks_it(seed):
    sp = make_pair(n_inliers=40, n_outliers=0, n_lines=0, noise=0.0, seed=seed)
    F = np.ascontiguousarray(sp.F)
    e = _epipole2(F)
    if abs(e[2]) < 1e-9 * np.linalg.norm(e):
        pytest.fail("scene with the epipole at infinity: pick another seed")
    a, b = sp.pts1[:7].copy(), sp.pts2[:7].copy()
    b[3] = _reflect_through_epipole(F, b[3])
    assert symmetric_epipolar_distance(F, a, b)[3] < 1e-6  # still on its epipolar line
    assert not oriented_consistent(F, a, b)
    # the seven-point solve of that sample finds F, and the constraint rejects it
    roots, _ = seven_point(a[None] / 640.0, b[None] / 640.0)
    T = np.diag([1 / 640.0, 1 / 640.0, 1.0])
    F_n = np.linalg.inv(T).T @ F @ np.linalg.inv(T)
    F_n /= np.linalg.norm(F_n)
    near = [G for G in roots if min(np.linalg.norm(G - F_n), np.linalg.norm(G + F_n)) < 1e-6]
    assert near and not any(oriented_consistent(G, a / 640.0, b / 640.0) for G in near)


def test_outlier_samples_models_are_mostly_dropped_all_inlier_ones_kept():
    sp = make_pair(n_inliers=300, n_outliers=300, n_lines=0, noise=0.5, seed=11)
    data = Correspondences.from_pixels(sp.pts1, sp.pts2)
    rng = np.random.default_rng(0)
    problem = {
        o: FundamentalProblem(data, "seven", 1.0, oriented=o) for o in (True, False)
    }  # fmt: skip
    samples = draw_samples(rng, np.arange(len(data)), 7, 2000)
    clean = sp.is_inlier[samples].all(axis=1)
    F_on, sid_on = problem[True].solve(samples)
    F_off, sid_off = problem[False].solve(samples)
    # the kept models are a subset of the unfiltered ones, sample by sample
    assert len(F_on) < len(F_off)
    for F, s in zip(F_on, sid_on, strict=True):
        same = F_off[sid_off == s]
        assert min(np.abs(same - F).max() for same in same) < 1e-12
    dirty_on = np.count_nonzero(~clean[sid_on])
    dirty_off = np.count_nonzero(~clean[sid_off])
    assert dirty_on < 0.5 * dirty_off, (dirty_on, dirty_off)
    # every all-inlier sample whose solve found a model good for the true matches (median
    # error < 2 px; an ill-conditioned sample's only root can be far off) keeps that model
    true1, true2 = sp.pts1[sp.is_inlier], sp.pts2[sp.is_inlier]
    kept_good = 0
    for s in np.flatnonzero(clean):
        best_off = min(
            np.median(symmetric_epipolar_distance(G, true1, true2)) for G in F_off[sid_off == s]
        )
        if best_off >= 2.0:
            continue
        kept = F_on[sid_on == s]
        assert len(kept) > 0
        best_on = min(np.median(symmetric_epipolar_distance(G, true1, true2)) for G in kept)
        assert best_on == pytest.approx(best_off)
        kept_good += 1
    assert kept_good >= 8


@pytest.mark.parametrize("method", ["sep4", "ransac7"])
def test_estimator_with_it_scores_fewer_models_and_finds_the_same_inliers(method):
    hyp, recovered = {}, {}
    for oriented in (True, False):
        hyp[oriented], recovered[oriented] = [], []
        for seed in range(4):
            sp = make_pair(n_inliers=150, n_outliers=250, n_lines=3, noise=0.3, seed=seed + 20)
            est = estimate_fundamental(
                sp.pts1, sp.pts2, sp.image_size, method=method, seed=seed, oriented=oriented
            )
            assert est.status == "ok"
            hyp[oriented].append(est.hypotheses)
            inl = np.count_nonzero(est.inliers & sp.is_inlier) / np.count_nonzero(sp.is_inlier)
            false = np.count_nonzero(est.inliers & ~sp.is_inlier)
            recovered[oriented].append(inl if false <= 0.05 * est.num_inliers else 0.0)
    assert min(recovered[True]) >= 0.95, recovered
    assert np.mean(recovered[True]) >= np.mean(recovered[False]) - 0.01
    assert np.median(hyp[True]) < 0.7 * np.median(hyp[False]), hyp


def test_fixed_line_points_take_part():
    """A sep4 arm's fixed line points are part of every sample: with one of them mirrored
    through the epipole (still on its epipolar line) the true F, which every sample's solve
    finds, is dropped from every sample."""
    sp = make_pair(n_inliers=120, n_outliers=0, n_lines=1, noise=0.0, seed=4)
    data = Correspondences.from_pixels(sp.pts1, sp.pts2)
    line = np.flatnonzero(sp.on_line)[[0, 5, 11]]  # spread along the line
    f1, f2 = sp.pts1[line].copy(), sp.pts2[line].copy()
    pool = np.setdiff1d(np.arange(len(data)), line)
    samples = draw_samples(np.random.default_rng(1), pool, 4, 50)
    F_true = sp.F / np.linalg.norm(sp.F)

    def true_models(oriented: bool, f2: np.ndarray) -> np.ndarray:
        arm = FundamentalProblem(
            data, "seven", 1.0, fixed1=f1, fixed2=f2, pool=pool, oriented=oriented
        )
        F, sid = arm.solve(samples)
        near = [min(np.abs(G - F_true).max(), np.abs(G + F_true).max()) < 1e-5 for G in F]
        return np.unique(sid[np.asarray(near, dtype=bool)]) if len(F) else np.zeros(0, int)

    solved = true_models(False, f2)
    assert len(solved) >= 30  # samples whose solve finds the true F (not ill-conditioned ones)
    assert np.array_equal(true_models(True, f2), solved)  # the constraint keeps it in every one
    f2[1] = _reflect_through_epipole(sp.F, f2[1])
    assert len(true_models(False, f2)) >= 30  # still solved through the mirrored point
    assert len(true_models(True, f2)) == 0
