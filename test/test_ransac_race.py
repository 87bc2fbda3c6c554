"""The RANSAC loop's race of several arms (line pairs): pooled stopping, lagging arms.

Arms here are stage-2 problems of the separable method (3 fixed correspondences + 5 sampled,
eight-point) on a synthetic scene with 65 % outliers, where F(5, r) is several hundred samples,
so every arm of the race joins before the search can stop.
"""

from __future__ import annotations

import numpy as np

from sepfm_ros.geometry.correspondences import Correspondences
from sepfm_ros.geometry.fundamental_problem import FundamentalProblem
from sepfm_ros.geometry.ransac import RaceOptions, ransac_trials, run_ransac
from sepfm_ros.geometry.synthetic import make_pair

SCENE = make_pair(n_inliers=120, n_outliers=270, n_lines=2, noise=0.3, seed=3)
DATA = Correspondences.from_pixels(SCENE.pts1, SCENE.pts2)


def _arm(fixed: np.ndarray) -> FundamentalProblem:
    pool = np.setdiff1d(np.arange(len(DATA)), fixed)
    return FundamentalProblem(
        DATA, "eight", 1.0, "msac", SCENE.pts1[fixed], SCENE.pts2[fixed], pool
    )


def _good_triple() -> np.ndarray:
    return np.flatnonzero(SCENE.on_line & SCENE.is_inlier)[:3]


def _wrong_triple(k: int) -> np.ndarray:
    return np.flatnonzero(~SCENE.is_inlier)[3 * k : 3 * k + 3]


def _run(arms: list[FundamentalProblem], seed: int):
    rng = np.random.default_rng(seed)
    return run_ransac(arms, rng, 0.99, 10000, race=RaceOptions())


def test_scene_needs_hundreds_of_samples():
    w = np.count_nonzero(SCENE.is_inlier) / len(DATA)
    assert ransac_trials(5, 1.0 - w) > 300  # arms join after 40, 80 and 160 samples


def test_agreeing_arms_pool_their_samples():
    # four equally good arms (the same true triple) draw all-inlier samples at the same rate, so
    # once each has shown its support their samples count together. Before pooling every arm drew
    # F(5, r) itself: 1.98x the samples of one arm on these seeds; pooled 1.44x (an arm's samples
    # count only after it found a model near the best, so joining still costs something).
    seeds = range(8)
    one = [_run([_arm(_good_triple())], s) for s in seeds]
    four = [_run([_arm(_good_triple()) for _ in range(4)], s) for s in seeds]
    assert all(r.converged for r in one + four)
    assert all(len(r.samples) == 4 for r in four)
    total_one = np.mean([sum(r.samples) for r in one])
    total_four = np.mean([sum(r.samples) for r in four])
    print(f"[race] samples: one good arm {total_one:.0f}, four good arms {total_four:.0f}")
    assert total_four < 1.7 * total_one
    inliers = np.count_nonzero(SCENE.is_inlier)
    for r in four:
        assert r.count >= 0.85 * inliers
        need = ransac_trials(5, 1.0 - r.count / len(DATA), 0.99)
        assert sum(r.samples) >= need


def test_lagging_arms_do_not_count_toward_stopping():
    # a good arm racing three arms with outlier triples: only the good arm's samples count, so
    # it alone draws F(5, r) samples for the best model's inlier ratio
    arms = [_arm(_good_triple())] + [_arm(_wrong_triple(k)) for k in range(3)]
    for seed in range(3):
        r = _run(arms, seed)
        assert r.converged and r.leader == 0
        need = ransac_trials(5, 1.0 - r.count / len(DATA), 0.99)
        assert r.samples[0] >= need
        assert r.count >= 0.85 * np.count_nonzero(SCENE.is_inlier)
