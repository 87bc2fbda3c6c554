"""PROSAC sampling, SPRT and bail-out early rejection of the shared RANSAC loop (robust/)."""

from __future__ import annotations

import numpy as np
import pytest

from sepfm_ros.geometry import estimate_fundamental
from sepfm_ros.geometry.epipolar import (
    distances_kernel,
    msac_cost,
    msac_kernel,
    reading_copy,
    sprt_msac_kernel,
    symmetric_epipolar_distance,
)
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
        bad, X1, X2, 1.0, order, reading_copy(X1, X2, order), *_sprt_args(0.6), np.inf, 0
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
            F, X1, X2, 1.0, order, reading_copy(X1, X2, order), *_sprt_args(eps), np.inf, 0
        )
        ref_cost, ref_count = msac_kernel(F, X1, X2, 1.0)
        assert not rejected[0] and read[0] == len(sp.pts1), seed
        assert cost[0] == ref_cost[0] and count[0] == ref_count[0]  # bit-identical


def _sprt_reference(F, X1, X2, t, order, log_A, log_in, log_out, bail_cost, bail_count):
    """The SPRT / bail-out scoring one point at a time, from the scalar distance kernel."""
    d_all = distances_kernel(F, X1, X2)
    N = X1.shape[1]
    out = []
    best = np.inf
    for m in range(len(F)):
        c, k, llr, j, stop, sprt = 0.0, 0, 0.0, 0, False, False
        while j < N:
            d = d_all[m, order[j]]
            j += 1
            inl = d < t
            k += int(inl)
            llr += log_in if inl else log_out
            c += d * d if inl else t * t
            if llr > log_A:
                stop = sprt = True
                break
            if c >= bail_cost and c > best and k + (N - j) < bail_count:
                stop = True
                break
        cost = np.inf if stop else msac_cost(F[m], X1, X2, t, np.inf)[0]
        if not stop:
            best = min(best, cost)
        out.append((cost, k, j, sprt))
    return out


@pytest.mark.parametrize("seed", range(6))
def test_vectorised_scoring_equals_reading_points_one_by_one(seed):
    """The chunked, vectorised kernels give the costs, counts, points read and rejections of
    scoring one point at a time, to the bit, with the SPRT, the bail-out, both and neither."""
    rng = np.random.default_rng(seed)
    sp = make_pair(n_inliers=150 + 40 * seed, n_outliers=120, noise=0.6, seed=seed)
    X1, X2 = _homog(sp.pts1), _homog(sp.pts2)
    scales = np.logspace(-7, -4, 6)[:, None, None]
    near = sp.F + scales * rng.normal(size=(6, 3, 3)) * np.abs(sp.F).max()
    far = rng.normal(size=(4, 3, 3))
    F = np.ascontiguousarray(np.concatenate([sp.F[None], near, far, np.zeros((1, 3, 3))]))
    t = 1.0 + 0.3 * seed
    ref_cost = np.array([msac_cost(f, X1, X2, t, np.inf)[0] for f in F])
    cost, count = msac_kernel(F, X1, X2, t)
    assert np.array_equal(cost, ref_cost)
    assert np.array_equal(count, (distances_kernel(F, X1, X2) < t).sum(axis=1))
    order = rng.permutation(X1.shape[1]).astype(np.int64)
    eps = float(np.mean(symmetric_epipolar_distance(sp.F, sp.pts1, sp.pts2) < t))
    finite = np.sort(ref_cost)
    for sprt in (_sprt_args(eps), (np.inf, 0.0, 0.0)):
        for bail in ((np.inf, 0), (float(finite[1]), int(count.max()))):
            got = sprt_msac_kernel(F, X1, X2, t, order, reading_copy(X1, X2, order), *sprt, *bail)
            want = _sprt_reference(F, X1, X2, t, order, *sprt, *bail)
            assert np.array_equal(got[0], [w[0] for w in want])
            assert got[1].tolist() == [w[1] for w in want]
            assert got[2].tolist() == [w[2] for w in want]
            assert got[3].tolist() == [w[3] for w in want]


def test_bailout_stops_only_models_that_cannot_matter():
    sp = make_pair(n_inliers=200, n_outliers=100, noise=0.5, seed=1)
    X1, X2 = _homog(sp.pts1), _homog(sp.pts2)
    F = np.ascontiguousarray(np.stack([sp.F, np.eye(3)[[1, 2, 0]] + 0.1]))
    ref_cost, _ = msac_kernel(F, X1, X2, 1.0)
    order = np.arange(len(sp.pts1), dtype=np.int64)
    bail = 0.5 * (ref_cost[0] + ref_cost[1])
    cost, _, read, rejected = sprt_msac_kernel(
        F, X1, X2, 1.0, order, reading_copy(X1, X2, order), np.inf, 0, 0, bail, 10**6
    )
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
