"""Minimal solvers, epipolar helpers and F(k, r) on exact synthetic data."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sepfm_ros.geometry import (
    fundamental_from_cameras,
    normalize_fundamental,
    ransac_trials,
    sampson_distance,
    symmetric_epipolar_distance,
)
from sepfm_ros.geometry.epipolar import (
    apply_transform,
    denormalize,
    homogeneous,
    homogeneous_columns,
    normalization_transform,
)
from sepfm_ros.geometry.solvers import eight_point, line_homography_3pt, seven_point
from sepfm_ros.geometry.solvers.line_homography import line_homography_lsq, transfer
from sepfm_ros.geometry.solvers.seven_point import real_cubic_roots
from sepfm_ros.geometry.synthetic import make_pair


def _sign_free_error(F: np.ndarray, G: np.ndarray) -> float:
    F, G = normalize_fundamental(F), normalize_fundamental(G)
    return float(min(np.abs(F - G).max(), np.abs(F + G).max()))


def test_real_cubic_roots_agree_with_numpy_on_random_and_hard_cubics():
    # the seven-point solver's closed-form cubic against numpy.roots (companion eigenvalues):
    # coefficients over 8 decades, cubics with a double or triple root, and a tiny leading
    # coefficient (a root near infinity, where the solver falls back to the companion matrix)
    rng = np.random.default_rng(0)
    cubics = [rng.normal(size=4) * np.exp(rng.normal(size=4) * 2.0) for _ in range(20000)]
    cubics += [np.poly([1.0, 1.0, -2.0]), np.poly([0.5, 0.5, 0.5]), np.poly([3.0, -1e-3, 1e-3])]
    cubics += [np.array([1e-9, 1.0, -3.0, 2.0])]
    out = np.empty(3)
    three = 0
    for c in cubics:
        n = real_cubic_roots(*c, out)
        ref = np.roots(c)
        real = np.sort(ref[np.abs(ref.imag) <= 1e-6 * (1.0 + np.abs(ref.real))].real)
        ours = np.sort(out[:n])
        three += n == 3
        # every root we return is a root (residual relative to the coefficients' scale) ...
        scale = np.abs(c).max() * np.maximum(1.0, np.abs(ours)) ** 3
        assert np.all(np.abs(np.polyval(c, ours)) <= 1e-9 * scale), (c, ours)
        # ... and each of numpy's simple real roots is one of ours (a multiple root is only
        # known to about the cube root of the precision, numpy's as well as ours)
        simple = [
            r for r in real
            if abs(np.polyval(np.polyder(c), r)) > 1e-3 * np.abs(c).max() * max(1.0, abs(r)) ** 2
        ]  # fmt: skip
        for r in simple:
            assert n and np.min(np.abs(ours - r)) <= 1e-6 * (1.0 + abs(r)), (c, ours, real)
        if len(simple) == len(real):
            assert n == len(real), (c, ours, real)
    assert three > 2000  # both branches (one and three real roots) were exercised


@pytest.fixture(scope="module")
def scene():
    return make_pair(n_inliers=60, n_outliers=0, n_lines=0, noise=0.0, seed=3)


def test_fundamental_from_cameras_satisfies_epipolar_constraint(scene):
    x1 = np.c_[scene.pts1, np.ones(len(scene.pts1))]
    x2 = np.c_[scene.pts2, np.ones(len(scene.pts2))]
    r = np.einsum("ni,ij,nj->n", x2, scene.F, x1)
    assert np.abs(r).max() < 1e-9
    assert np.isclose(np.linalg.norm(scene.F), 1.0)
    assert np.linalg.matrix_rank(scene.F, tol=1e-9) == 2
    # independent of the cameras' projective scale
    assert _sign_free_error(fundamental_from_cameras(3 * scene.P1, -scene.P2), scene.F) < 1e-10


def test_seven_point_recovers_exact_F(scene):
    T1, T2 = normalization_transform(scene.pts1), normalization_transform(scene.pts2)
    x1, x2 = apply_transform(T1, scene.pts1), apply_transform(T2, scene.pts2)
    idx = np.arange(7 * 5).reshape(5, 7)
    F_n, sample = seven_point(x1[idx], x2[idx])
    assert len(F_n) >= 5 and set(sample) == set(range(5))
    F = denormalize(F_n, T1, T2)
    for s in range(5):
        errs = [_sign_free_error(G, scene.F) for G in F[sample == s]]
        assert min(errs) < 1e-8
        # every root is a rank-2 matrix through the 7 points
        for G in F[sample == s]:
            assert abs(np.linalg.det(G / np.linalg.norm(G))) < 1e-9


def test_eight_point_recovers_exact_F(scene):
    T1, T2 = normalization_transform(scene.pts1), normalization_transform(scene.pts2)
    x1, x2 = apply_transform(T1, scene.pts1), apply_transform(T2, scene.pts2)
    idx = np.arange(8 * 4).reshape(4, 8)
    F = denormalize(eight_point(x1[idx], x2[idx]), T1, T2)
    for G in F:
        assert _sign_free_error(G, scene.F) < 1e-8
    G = denormalize(eight_point(x1, x2), T1, T2)  # least squares on all
    assert _sign_free_error(G, scene.F) < 1e-8


def test_line_homography_minimal_and_least_squares():
    rng = np.random.default_rng(0)
    H = rng.normal(size=(2, 2))
    t1 = rng.uniform(0, 1, 10)
    t2 = transfer(H, t1)
    ab1 = np.stack([1 - t1, t1], -1)
    ab2 = np.stack([1 - t2, t2], -1)
    Hs = line_homography_3pt(ab1[None, :3], ab2[None, :3])[0]
    assert np.allclose(transfer(Hs, t1), t2, atol=1e-9)
    Hl = line_homography_lsq(ab1, ab2)
    assert np.allclose(transfer(Hl, t1), t2, atol=1e-9)
    # a wrong correspondence is not reproduced
    assert abs(transfer(Hs, np.array([0.5]))[0] - (transfer(H, np.array([0.5]))[0] + 0.1)) > 0.05


def test_symmetric_epipolar_and_sampson_distance_hand_computed():
    # F = [t]_x for t = (1, 0, 0): pure x translation; epipolar lines are rows v = const.
    F = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
    p1 = np.array([[10.0, 20.0], [5.0, 5.0]])
    p2 = np.array([[30.0, 23.0], [9.0, 5.0]])
    # x2^T F x1 = v1 - v2 ... line in image 2 through v = v1: distance |v2 - v1|
    d = symmetric_epipolar_distance(F, p1, p2)
    assert np.allclose(d, [3.0, 0.0])
    s = sampson_distance(F, p1, p2)
    assert np.allclose(s, [3.0 / np.sqrt(2.0), 0.0])
    # batched form agrees
    assert np.allclose(symmetric_epipolar_distance(np.stack([F, 2 * F]), p1, p2), [d, d])
    # the (3, N) columns the compiled distances read: (x, y, 1), contiguous, float64
    cols = homogeneous_columns(p2.astype(np.float32))
    assert cols.flags.c_contiguous and cols.dtype == np.float64
    assert np.array_equal(cols, homogeneous(p2).T)


@pytest.mark.parametrize("k,r", [(7, 0.5), (3, 0.6), (4, 0.6), (8, 0.3), (1, 0.0)])
def test_ransac_trials_formula(k, r):
    expected = math.ceil(math.log(1 - 0.99) / math.log(1 - (1 - r) ** k)) if r > 0 else 1
    assert ransac_trials(k, r, 0.99) == max(1, expected)


def test_ransac_trials_paper_values():
    # the paper quotes 71 for F(3, 0.6) (log(0.01) / log(1 - 0.4^3) = 69.6, rounded up: 70)
    # and 178 for F(4, 0.6) at 99 % confidence
    assert ransac_trials(3, 0.6) == 70
    assert ransac_trials(4, 0.6) == 178
    assert ransac_trials(7, 0.9, max_trials=1000) == 1000
    with pytest.raises(ValueError):
        ransac_trials(0, 0.5)
    with pytest.raises(ValueError):
        ransac_trials(7, 1.0)


def test_draw_samples_distinct_uniform_and_seeded():
    from collections import Counter

    from sepfm_ros.geometry.robust.samplers import draw_samples

    pool = np.arange(100, 110)  # samples are entries of the pool, not positions
    s = draw_samples(np.random.default_rng(5), pool, 3, 60000)
    assert s.shape == (60000, 3) and set(np.unique(s)) == set(pool.tolist())
    assert all(len(set(row)) == 3 for row in s.tolist())
    subsets = Counter(tuple(sorted(row)) for row in s.tolist())
    assert len(subsets) == 120  # every 3-subset of 10 occurs ...
    counts = np.array(list(subsets.values()))
    expected = 60000 / 120
    chi2 = float(((counts - expected) ** 2 / expected).sum())
    assert chi2 < 200, chi2  # ... about equally often (119 dof: 99.9 % quantile ~ 170)
    # the same seed gives the same samples; a pool of exactly k is a permutation
    again = draw_samples(np.random.default_rng(5), pool, 3, 60000)
    assert np.array_equal(s, again)
    assert sorted(draw_samples(np.random.default_rng(1), pool, 10, 1)[0]) == pool.tolist()
    with pytest.raises(ValueError):
        draw_samples(np.random.default_rng(1), pool, 11, 1)


def test_smallest_eigenvector_by_inverse_iteration_agrees_with_eigh():
    # the refits' inverse iteration against LAPACK eigh: Gram matrices of real design rows,
    # an exactly singular one (noise-free data), and starts near and far from the answer;
    # two equal smallest eigenvalues and a zero start fall back to eigh's own vector
    from sepfm_ros.geometry.fundamental.refine import smallest_eigenvector

    rng = np.random.default_rng(0)
    sp = make_pair(n_inliers=60, n_outliers=0, noise=0.0, seed=3)
    n = len(sp.pts1)
    x = np.c_[sp.pts1 / 500.0, np.ones(n)]
    y = np.c_[sp.pts2 / 500.0, np.ones(n)]
    exact = np.einsum("ni,nj->nij", y, x).reshape(n, 9)
    cases = [exact.T @ exact]  # rank 8
    for _ in range(200):
        A = rng.normal(size=(int(rng.integers(9, 40)), 9)) * rng.uniform(0.01, 10.0, 9)
        cases.append(A.T @ A)
    far = 0
    for G in cases:
        ref = np.linalg.eigh(G)[1][:, 0]
        for start in (ref + rng.normal(scale=0.05, size=9), rng.normal(size=9)):
            v = smallest_eigenvector(G, start)
            assert abs(np.linalg.norm(v) - 1.0) < 1e-12
            assert min(np.abs(v - ref).max(), np.abs(v + ref).max()) < 1e-8
            far += 1
    assert far == 2 * len(cases)
    G = np.diag([1.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0])  # a double smallest eigenvalue
    v = smallest_eigenvector(G, np.ones(9))
    assert np.allclose(G @ v, v) and abs(np.linalg.norm(v) - 1.0) < 1e-12
    assert np.array_equal(smallest_eigenvector(G, np.zeros(9)), np.linalg.eigh(G)[1][:, 0])


def test_weighted_design_gram_is_the_weighted_sum_of_row_outer_products():
    """The refits' Gram matrix (weighted design rows as columns, ``column_gram``) against
    sum_k w_k^2 r_k r_k^T of the epipolar rows r = kron([x2, 1], [x1, 1]), on a subset of rows."""
    from sepfm_ros.geometry.fundamental.refine import _weighted_design
    from sepfm_ros.geometry.solvers.design import column_gram

    rng = np.random.default_rng(4)
    x1, x2 = rng.normal(size=(300, 2)), rng.normal(size=(300, 2))
    idx = np.sort(rng.choice(300, 211, replace=False))
    w = rng.uniform(0.1, 1.0, len(idx))
    R = np.empty((9, len(idx)))
    _weighted_design(x1, x2, idx, w, R)
    rows = np.einsum(
        "ka,kb->kab", np.c_[x2[idx], np.ones(len(idx))], np.c_[x1[idx], np.ones(len(idx))]
    )
    rows = rows.reshape(len(idx), 9)
    expected = (rows * (w * w)[:, None]).T @ rows
    G = column_gram(R, len(idx))
    assert np.allclose(G, expected, rtol=1e-12, atol=1e-12 * np.abs(expected).max())
    assert np.array_equal(G, G.T)
    # only the first m columns count
    assert np.allclose(column_gram(R, 50), (R[:, :50] @ R[:, :50].T), rtol=1e-12, atol=1e-10)
