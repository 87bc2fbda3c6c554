"""The RANSAC loop's race of several arms (line pairs): pooled stopping, lagging arms, and a
wrong line pair on repetitive texture that an H_e fits exactly.

Arms here are stage-2 problems of the separable method (3 fixed correspondences + 5 sampled,
eight-point) on a synthetic scene with 65 % outliers, where F(5, r) is several hundred samples,
so every arm of the race joins before the search can stop.
"""

from __future__ import annotations

import numpy as np
import pytest

from sepfm_ros.geometry import estimate_fundamental, symmetric_epipolar_distance
from sepfm_ros.geometry.fundamental.correspondences import Correspondences
from sepfm_ros.geometry.fundamental.problem import FundamentalProblem
from sepfm_ros.geometry.robust.loop import run_ransac
from sepfm_ros.geometry.robust.options import RaceOptions
from sepfm_ros.geometry.robust.trials import ransac_trials
from sepfm_ros.geometry.synthetic import SyntheticPair, make_pair

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


def repetitive_row_scene(seed: int) -> tuple[SyntheticPair, np.ndarray, np.ndarray, np.ndarray]:
    """A scene whose strongest line pair is a row of repeated texture matched one period off.

    150 general and 2 x 12 line correspondences, 150 outliers, 0.3 px noise, and in front 25
    wrong matches along one 3D row of equally spaced points, point i of image 1 matched with
    point i + 1 of image 2 (a row of windows): they lie on an image line pair and follow a 1D
    homography exactly, so Hough ranks them first and stage 1 fits an H_e to all of them, but
    the F through a triple of them is wrong. Returns (scene, pts1, pts2, is_inlier): inliers are
    the matches within 1 px of the true F.
    """
    sp = make_pair(n_inliers=150, n_outliers=150, n_lines=2, noise=0.3, seed=seed)
    rng = np.random.default_rng(100 + seed)
    w, h = sp.image_size
    n_rep, centre = 25, np.array([0.0, 0.0, 6.0])

    def project(P: np.ndarray, X: np.ndarray) -> np.ndarray:
        x = np.concatenate([X, np.ones((len(X), 1))], axis=1) @ P.T
        return x[:, :2] / x[:, 2:]

    def inside(x: np.ndarray) -> bool:
        return bool(((x[:, 0] > 1) & (x[:, 0] < w - 2) & (x[:, 1] > 1) & (x[:, 1] < h - 2)).all())

    while True:
        A, B = centre + rng.uniform(-2.5, 2.5, (2, 3)) * np.array([1.0, 0.8, 1.0])
        if np.linalg.norm(B - A) < 2.5:
            continue
        X = A + np.linspace(0.0, 1.0, n_rep + 1)[:, None] * (B - A)
        x1, x2 = project(sp.P1, X), project(sp.P2, X)
        if inside(x1) and inside(x2):
            break
    r1 = x1[:-1] + rng.normal(0.0, 0.3, (n_rep, 2))
    r2 = x2[1:] + rng.normal(0.0, 0.3, (n_rep, 2))
    pts1 = np.concatenate([r1, sp.pts1])
    pts2 = np.concatenate([r2, sp.pts2])
    # the truth is the true F's verdict: a row along an epipolar line pair matched one period
    # off is as consistent with it as a right match (and indistinguishable by any F)
    inl = np.concatenate([np.zeros(n_rep, bool), sp.is_inlier])
    inl[:n_rep] = symmetric_epipolar_distance(sp.F, r1, r2) < 1.0
    return sp, pts1, pts2, inl


@pytest.mark.parametrize("order", ["shuffled", "row first, periodic check", "row first, no PROSAC"])
def test_good_line_pair_overtakes_a_wrong_one_on_repetitive_texture(order):
    # The wrong pair leads the race; a good pair joining later must get samples at the
    # leader's pace and its own local optimisation to overtake it. Before (new arms' batches
    # grew from 1, LO only for models beating every arm's best raw model): sep4 kept the wrong
    # F on 3 of these 12 scenes (57, 64 and 53 % of the true inliers), sep5 on 1 (65 %).
    # Match order is a quality claim to PROSAC (on by default): "shuffled" makes none; "row
    # first" lists the periodic row as the best matches (a ratio test would not), so PROSAC
    # draws it first. With PROSAC and the row first, sep4 without the periodic line-pair check
    # (off by default) ends on a wrong F (55 % of the true inliers, the row's 24 wrong matches
    # as inliers) or a slightly wrong one on 2 of the 12 scenes; with it (the row's pair joins
    # the race last, its matches are not sampled by the other arms) on none.
    recovered = {"sep4": [], "sep5": [], "ransac7": []}
    hypotheses = {m: [] for m in recovered}
    samples = {m: [] for m in recovered}
    options = {
        "shuffled": {},
        "row first, periodic check": {"periodic_check": True},
        "row first, no PROSAC": {"prosac": False},
    }[order]
    for seed in range(12):
        sp, pts1, pts2, inl = repetitive_row_scene(seed)
        if order == "shuffled":
            perm = np.random.default_rng(seed).permutation(len(pts1))
            pts1, pts2, inl = pts1[perm], pts2[perm], inl[perm]
        for method in recovered:
            est = estimate_fundamental(pts1, pts2, sp.image_size, method=method, seed=0, **options)
            assert est.F is not None
            false = np.count_nonzero(est.inliers & ~inl)
            share = np.count_nonzero(est.inliers & inl) / np.count_nonzero(inl)
            recovered[method].append(share if false <= 0.05 * np.count_nonzero(inl) else 0.0)
            hypotheses[method].append(est.hypotheses)
            samples[method].append(est.samples)
    print(
        "[race] repetitive row, recovered:",
        {m: np.round(v, 2).tolist() for m, v in recovered.items()},
    )
    print("[race] repetitive row, hypotheses:", hypotheses)
    ok = {m: sum(r >= 0.95 for r in v) for m, v in recovered.items()}
    assert ok["ransac7"] == 12  # the scene itself is solvable
    assert ok["sep5"] == 12
    assert ok["sep4"] >= 11  # one scene's good pairs join late and are badly conditioned
    if order == "row first, periodic check":
        # no scene ends on the row's wrong F (without the check one does, at about half of the
        # true inliers); the scene short of 0.95 holds the right F with a 0.948 mask
        assert min(recovered["sep4"]) >= 0.9
    for m in ("sep4", "sep5"):
        # the paper's saving, in samples (F(k, r)) and in models scored
        assert np.median(samples[m]) < 0.6 * np.median(samples["ransac7"])
        assert np.median(hypotheses[m]) < 0.5 * np.median(hypotheses["ransac7"])


def test_model_rule_pools_arms_whose_models_hold_the_best_models_inliers():
    # four equally good arms find models that share the best model's inliers, so under the
    # "model" rule their samples pool as under the support rule; an outlier triple's models
    # do not hold those inliers, so the good arm alone draws F(5, r) samples
    race = RaceOptions(pool_rule="model", pool_ratio=0.8)
    seeds = range(8)
    one = [_run([_arm(_good_triple())], s) for s in seeds]
    four = [
        run_ransac([_arm(_good_triple()) for _ in range(4)], np.random.default_rng(s), race=race)
        for s in seeds
    ]
    assert all(r.converged for r in one + four)
    total_one = np.mean([sum(r.samples) for r in one])
    total_four = np.mean([sum(r.samples) for r in four])
    assert total_four < 1.7 * total_one
    arms = [_arm(_good_triple())] + [_arm(_wrong_triple(k)) for k in range(3)]
    for seed in range(3):
        r = run_ransac(arms, np.random.default_rng(seed), race=race)
        assert r.converged and r.leader == 0
        assert r.samples[0] >= ransac_trials(5, 1.0 - r.count / len(DATA), 0.99)


def test_pool_ratio_above_every_arm_leaves_the_leader_alone():
    # pool_ratio 1.5: no other arm's support reaches it, so the leader's own samples must reach
    # F(5, r): more samples in all than when the four equally good arms pool
    seeds = range(4)
    alone = RaceOptions(pool_ratio=1.5)
    for s in seeds:
        r = run_ransac([_arm(_good_triple()) for _ in range(4)], np.random.default_rng(s),
                       race=alone)  # fmt: skip
        assert r.converged
        assert r.samples[r.leader] >= ransac_trials(5, 1.0 - r.count / len(DATA), 0.99)
