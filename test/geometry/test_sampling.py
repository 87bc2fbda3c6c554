"""PROSAC sampling, SPRT and bail-out early rejection of the shared RANSAC loop (robust/)."""

from __future__ import annotations

import numpy as np
import pytest

from sepfm_ros.geometry import estimate_fundamental
from sepfm_ros.geometry.epipolar import msac_kernel, sprt_msac_kernel, symmetric_epipolar_distance
from sepfm_ros.geometry.robust.samplers import ProsacSampler, prosac_schedule
from sepfm_ros.geometry.robust.sprt import sprt_threshold
from sepfm_ros.geometry.synthetic import make_pair


def test_prosac_schedule_grows_to_the_pool():
    s = prosac_schedule(100, 7, 1000)
    assert s[0] == 1 and len(s) == 100 - 7 + 1
    assert np.all(np.diff(s) >= 1)  # every n gets at least one sample
    assert 1000 <= s[-1] <= 1000 + 100  # T'_N is about T_N


def test_prosac_draws_from_the_top_early():
    pool = np.arange(500) * 3 + 1  # entries, not positions
    sampler = ProsacSampler(pool, 7, growth=10000)
    smp = sampler.draw(np.random.default_rng(0), 300)
    assert sorted(smp[0]) == list(pool[:7])  # the first sample is the top 7
    for t in range(1, 301):
        n = sampler.top(t)
        pos = (smp[t - 1] - 1) // 3
        assert len(set(pos)) == 7
        assert pos.max() == n - 1  # the n-th entry plus k - 1 from the top n - 1
    assert sampler.top(300) < 300  # still far from the whole pool of 500


def test_prosac_covers_the_pool_later_then_uniform():
    pool = np.arange(60)
    sampler = ProsacSampler(pool, 5, growth=40)
    end = int(sampler.schedule[-1])
    smp = sampler.draw(np.random.default_rng(1), end + 3000)
    assert set(np.unique(smp[:end])) == set(pool)  # grown to the whole pool
    late = smp[end:]
    assert np.all((late >= 0) & (late < 60))
    assert np.all([len(set(r)) == 5 for r in late])
    # uniform: each entry about 5/60 of the late samples, the max no longer forced
    freq = np.bincount(late.ravel(), minlength=60) / len(late)
    assert np.all(np.abs(freq - 5 / 60) < 0.03)
    assert np.mean(late.max(axis=1) == 59) < 0.2


def test_prosac_same_seed_same_samples():
    pool = np.arange(200)
    a = ProsacSampler(pool, 7, 5000).draw(np.random.default_rng(7), 100)
    b = ProsacSampler(pool, 7, 5000).draw(np.random.default_rng(7), 100)
    c = ProsacSampler(pool, 7, 5000).draw(np.random.default_rng(8), 100)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)


def _sprt_args(eps: float, delta: float = 0.01):
    A = sprt_threshold(eps, delta, 200.0, 2.0)
    return np.log(A), np.log(delta / eps), np.log((1 - delta) / (1 - eps))


def _homog(p):
    return np.ascontiguousarray(np.concatenate([p, np.ones((len(p), 1))], axis=1).T)


def test_sprt_rejects_a_bad_model_after_few_points():
    sp = make_pair(n_inliers=300, n_outliers=100, noise=0.5, seed=3)
    X1, X2 = _homog(sp.pts1), _homog(sp.pts2)
    rng = np.random.default_rng(0)
    bad = rng.normal(size=(20, 3, 3))
    bad /= np.linalg.norm(bad.reshape(20, -1), axis=1)[:, None, None]
    order = rng.permutation(len(sp.pts1)).astype(np.int64)
    cost, count, read, rejected = sprt_msac_kernel(
        bad, X1, X2, 1.0, order, *_sprt_args(0.6), np.inf, 0
    )
    assert rejected.all() and np.all(np.isinf(cost))
    assert np.median(read) < 30 and read.max() < 0.25 * len(sp.pts1)


def test_sprt_keeps_the_true_model_and_its_exact_cost():
    for seed in range(40):
        sp = make_pair(n_inliers=200, n_outliers=100, noise=0.5, seed=seed)
        X1, X2 = _homog(sp.pts1), _homog(sp.pts2)
        F = np.ascontiguousarray(sp.F[None])
        eps = np.mean(symmetric_epipolar_distance(sp.F, sp.pts1, sp.pts2) < 1.0)
        order = np.random.default_rng(seed).permutation(len(sp.pts1)).astype(np.int64)
        cost, count, read, rejected = sprt_msac_kernel(
            F, X1, X2, 1.0, order, *_sprt_args(eps), np.inf, 0
        )
        ref_cost, ref_count = msac_kernel(F, X1, X2, 1.0)
        assert not rejected[0] and read[0] == len(sp.pts1), seed
        assert cost[0] == ref_cost[0] and count[0] == ref_count[0]  # bit-identical


def test_bailout_stops_only_models_that_cannot_matter():
    sp = make_pair(n_inliers=200, n_outliers=100, noise=0.5, seed=1)
    X1, X2 = _homog(sp.pts1), _homog(sp.pts2)
    F = np.ascontiguousarray(np.stack([sp.F, np.eye(3)[[1, 2, 0]] + 0.1]))
    ref_cost, _ = msac_kernel(F, X1, X2, 1.0)
    order = np.arange(len(sp.pts1), dtype=np.int64)
    bail = 0.5 * (ref_cost[0] + ref_cost[1])
    cost, _, read, rejected = sprt_msac_kernel(F, X1, X2, 1.0, order, np.inf, 0, 0, bail, 10**6)
    assert cost[0] == ref_cost[0] and np.isinf(cost[1]) and not rejected.any()
    assert read[1] < len(sp.pts1)


@pytest.mark.parametrize("method", ["ransac7", "sep5"])
def test_bailout_alone_reproduces_the_plain_run(method):
    sp = make_pair(n_inliers=150, n_outliers=150, noise=0.5, n_lines=3, seed=5)
    plain = {"prosac": False, "sprt": False}
    a = estimate_fundamental(
        sp.pts1, sp.pts2, sp.image_size, method=method, seed=2, bailout=False, **plain
    )
    b = estimate_fundamental(
        sp.pts1, sp.pts2, sp.image_size, method=method, seed=2, bailout=True, **plain
    )
    assert np.array_equal(a.F, b.F) and a.hypotheses == b.hypotheses


@pytest.mark.parametrize("method", ["ransac7", "sep4"])
def test_prosac_sprt_recover_f_with_outliers_last(method):
    for seed in range(3):
        sp = make_pair(n_inliers=120, n_outliers=210, noise=0.5, n_lines=3, seed=seed)
        order = np.argsort(~sp.is_inlier, kind="stable")  # outliers at the end (60 %+)
        p1, p2 = sp.pts1[order], sp.pts2[order]
        e = estimate_fundamental(
            p1, p2, sp.image_size, method=method, seed=seed, prosac=True, sprt=True, bailout=True
        )
        inl = sp.is_inlier[order]
        d = symmetric_epipolar_distance(e.F, p1[inl], p2[inl])
        assert np.median(d) < 1.0, seed
        assert e.num_inliers >= 0.8 * inl.sum()
