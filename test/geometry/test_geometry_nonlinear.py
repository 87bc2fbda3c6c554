"""Levenberg-Marquardt refinement of F on the truncated symmetric epipolar error (nonlinear.py)."""

from __future__ import annotations

import numpy as np
import pytest

from sepfm_ros.geometry import estimate_fundamental
from sepfm_ros.geometry.epipolar import msac_kernel, symmetric_epipolar_distance
from sepfm_ros.geometry.fundamental.correspondences import Correspondences
from sepfm_ros.geometry.fundamental.nonlinear import (
    FINAL_TRUNCATION,
    LM_BAND,
    LM_MODEL_START,
    WIDE_MIN_PX,
    WIDE_TRUNCATION,
    _compose,
    _parameter_derivatives,
    _rotated,
    _solve_damped,
    _truncated_pass,
    multi_scale_cost,
    noise_truncation,
    polish_final,
    polish_local_optimization,
    refine_truncated,
)
from sepfm_ros.geometry.solvers.design import column_gram
from sepfm_ros.geometry.synthetic import make_pair


def _cost(F: np.ndarray, data: Correspondences, t: float) -> float:
    return float(msac_kernel(np.ascontiguousarray(F[None]), data.X1, data.X2, t)[0][0])


def _perturbed(F: np.ndarray, rng: np.random.Generator, scale: float) -> np.ndarray:
    """F with every entry scaled by 1 + ``scale`` x N(0, 1) (rank 3 in general)."""
    return F / np.linalg.norm(F) * (1.0 + scale * rng.normal(size=(3, 3)))


def _rotation(w: np.ndarray) -> np.ndarray:
    """exp([w]x) by the matrix exponential's series (reference for the Rodrigues form)."""
    K = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    R, term = np.eye(3), np.eye(3)
    for k in range(1, 30):
        term = term @ K / k
        R = R + term
    return R


@pytest.mark.parametrize("seed", range(3))
def test_lm_step_parts_match_their_reference_forms(seed):
    """The scalar-code parts of one LM step (rotation, parameter derivatives, damped solve,
    the pass that scores and writes the rows) against plain numpy forms of the same things."""
    rng = np.random.default_rng(seed)
    U = _rotation(rng.normal(size=3))
    V = _rotation(rng.normal(size=3))
    sigma = 0.3 + 0.5 * rng.random()
    for w in (rng.normal(size=3), np.array([1e-14, 0.0, -2e-14]), np.zeros(3)):
        assert np.allclose(_rotated(U, *w), U @ _rotation(w), atol=1e-14)
    # dF/dp by central differences of F(p) = U exp([w]x) diag(1, s, 0) (V exp([z]x))^T
    D = _parameter_derivatives(U, sigma, V)
    h = 1e-6
    for p in range(7):
        dp = np.zeros(7)
        dp[p] = h
        Fp = _compose(_rotated(U, *dp[:3]), sigma + dp[6], _rotated(V, *dp[3:6]))
        Fm = _compose(_rotated(U, *-dp[:3]), sigma - dp[6], _rotated(V, *-dp[3:6]))
        assert np.allclose(D[p], ((Fp - Fm) / (2 * h)).ravel(), atol=1e-8)
    A = rng.normal(size=(12, 7))
    JtJ, Jte = A.T @ A, rng.normal(size=7)
    for lam in (0.0, 1e-3, 10.0):
        damped = JtJ + lam * np.diag(np.maximum(np.diag(JtJ), 1e-12))
        assert np.allclose(_solve_damped(JtJ, Jte, lam), -np.linalg.solve(damped, Jte))
    # the pass: cost and rows of the matches inside the truncation, by finite differences of e
    pair = make_pair(n_inliers=60, n_outliers=30, noise=0.5, seed=seed)
    data = Correspondences.from_pixels(pair.pts1, pair.pts2)
    Fn = np.linalg.inv(data.T2).T @ pair.F @ np.linalg.inv(data.T1)
    s1, s2, t = data.T1[0, 0], data.T2[0, 0], 1.5

    h1, h2 = np.c_[data.x1, np.ones(len(data))], np.c_[data.x2, np.ones(len(data))]

    def err(F: np.ndarray) -> np.ndarray:
        """(N,) signed symmetric epipolar distance, px, of normalised F."""
        d = symmetric_epipolar_distance(data.T2.T @ F @ data.T1, pair.pts1, pair.pts2)
        return d * np.sign(np.einsum("ij,jk,ik->i", h2, F, h1))

    e = err(Fn)
    n = len(data)
    rows, e_in = np.empty((9, n)), np.empty(n)
    cost, m = _truncated_pass(Fn, data.x1, data.x2, s1, s2, t * t, rows, e_in)
    inside = np.abs(e) < t
    assert m == np.count_nonzero(inside) and 0 < m < n
    assert np.isclose(cost, np.minimum(e * e, t * t).sum())
    assert np.allclose(e_in[:m], e[inside])
    for a in range(9):
        dF = np.zeros(9)
        dF[a] = 1e-7
        de = (err(Fn + dF.reshape(3, 3)) - err(Fn - dF.reshape(3, 3))) / 2e-7
        assert np.allclose(rows[a, :m], de[inside], rtol=1e-4, atol=1e-6)
    # the normal-equation products of those rows
    G = rows[:, :m].T
    assert np.allclose(column_gram(rows, m), G.T @ G, rtol=1e-12, atol=1e-12 * np.abs(G).max() ** 2)


@pytest.mark.parametrize("seed", range(6))
def test_refinement_from_a_perturbed_F_reaches_the_noise_floor_and_keeps_rank_2(seed):
    pair = make_pair(n_inliers=150, n_outliers=60, noise=0.3, seed=seed)
    data = Correspondences.from_pixels(pair.pts1, pair.pts2)
    rng = np.random.default_rng(seed)
    start = _perturbed(pair.F, rng, 0.003)
    t = 1.0
    G = refine_truncated(start, data, t, iterations=50)
    assert G.shape == (3, 3) and np.isclose(np.linalg.norm(G), 1.0)
    s = np.linalg.svd(G, compute_uv=False)
    assert s[2] < 1e-9 * s[0]  # rank 2 held by the parametrisation
    # much better than the start, and about as good as the true F on its own matches
    assert _cost(G, data, t) < _cost(start, data, t)
    assert _cost(G, data, t) <= 1.03 * _cost(pair.F, data, t)
    d = symmetric_epipolar_distance(G, pair.pts1, pair.pts2)[pair.is_inlier]
    assert np.median(d) < 0.4


def test_refinement_never_raises_the_cost_of_its_start():
    """From the (rank-2) true F on noisy matches the refinement may only lower the cost."""
    for seed in range(5):
        pair = make_pair(n_inliers=120, n_outliers=40, noise=0.5, seed=seed)
        data = Correspondences.from_pixels(pair.pts1, pair.pts2)
        for t in (0.5, 1.0, 3.0):
            G = refine_truncated(pair.F, data, t)
            assert _cost(G, data, t) <= _cost(pair.F, data, t) + 1e-9


def test_zero_iterations_return_the_start_at_rank_2():
    pair = make_pair(n_inliers=80, noise=0.2, seed=1)
    data = Correspondences.from_pixels(pair.pts1, pair.pts2)
    G = refine_truncated(pair.F, data, 1.0, iterations=0)
    F = pair.F / np.linalg.norm(pair.F)
    assert np.allclose(G, F * np.sign(F.ravel() @ G.ravel()), atol=1e-9)


def test_noise_truncation_follows_the_matches_noise_within_its_clamp():
    thr = 1.0
    got = []
    for noise in (0.05, 0.3, 1.5):
        pair = make_pair(n_inliers=200, n_outliers=20, noise=noise, seed=3)
        data = Correspondences.from_pixels(pair.pts1, pair.pts2)
        got.append(noise_truncation(pair.F, data, thr))
    assert got[0] == pytest.approx(thr)  # precise matches: fitted at the threshold
    assert thr < got[1] < LM_BAND * thr  # noisier: a wider truncation
    assert got[2] == pytest.approx(LM_BAND * thr)  # clamped
    assert got[0] <= got[1] <= got[2]


def test_polish_returns_both_starts_refined():
    pair = make_pair(n_inliers=150, n_outliers=50, noise=0.4, seed=2)
    data = Correspondences.from_pixels(pair.pts1, pair.pts2)
    rng = np.random.default_rng(0)
    model = _perturbed(pair.F, rng, 0.01)
    start = _perturbed(pair.F, rng, 0.002)
    out = polish_local_optimization(model, start, data, 1.0)
    assert out.shape == (2, 3, 3) and np.isfinite(out).all()  # noisy: both starts
    t = noise_truncation(start, data, 1.0)
    assert _cost(out[1], data, t) < _cost(model, data, t)
    assert _cost(out[0], data, t) <= _cost(start, data, t) + 1e-6


def test_degenerate_start_comes_back_unchanged_and_finite():
    pair = make_pair(n_inliers=60, seed=0)
    data = Correspondences.from_pixels(pair.pts1, pair.pts2)
    G = refine_truncated(np.zeros((3, 3)), data, 1.0)
    assert np.array_equal(G, np.zeros((3, 3)))
    bad = pair.F.copy()
    bad[0, 0] = np.nan
    assert np.array_equal(refine_truncated(bad, data, 1.0), bad, equal_nan=True)


@pytest.mark.parametrize("lo", ["lm", "sampson", "plain"])
def test_every_lo_scheme_recovers_a_synthetic_F(lo):
    pair = make_pair(n_inliers=200, n_outliers=100, noise=0.5, seed=4)
    est = estimate_fundamental(pair.pts1, pair.pts2, pair.image_size, seed=0, lo=lo)
    assert est.status == "ok"
    d = symmetric_epipolar_distance(est.F, pair.pts1, pair.pts2)[pair.is_inlier]
    assert np.median(d) < 0.6


def test_polish_keeps_to_the_best_refit_on_precise_matches():
    """Precise matches (truncation under LM_MODEL_START x threshold): the sample's own model is
    not refined, only the best refit."""
    pair = make_pair(n_inliers=150, n_outliers=50, noise=0.05, seed=2)
    data = Correspondences.from_pixels(pair.pts1, pair.pts2)
    rng = np.random.default_rng(0)
    model = _perturbed(pair.F, rng, 0.01)
    start = pair.F / np.linalg.norm(pair.F)
    assert noise_truncation(start, data, 1.0) < LM_MODEL_START
    out = polish_local_optimization(model, start, data, 1.0)
    assert out.shape == (1, 3, 3)
    t = noise_truncation(start, data, 1.0)
    assert _cost(out[0], data, t) <= _cost(start, data, t) + 1e-9


def test_final_polish_refines_the_model_of_noisy_matches_only():
    """polish_final: precise matches keep F as it is; on noisy ones F is refined at
    FINAL_TRUNCATION x the threshold and kept only if no match within the threshold (or, given
    an off-plane mask, no off-plane one) is lost."""
    precise = make_pair(n_inliers=150, n_outliers=50, noise=0.05, seed=2)
    data = Correspondences.from_pixels(precise.pts1, precise.pts2)
    F = precise.F / np.linalg.norm(precise.F)
    assert polish_final(F, data, 1.0) is F
    noisy = make_pair(n_inliers=150, n_outliers=60, n_lines=3, noise=0.5, seed=0)
    data = Correspondences.from_pixels(noisy.pts1, noisy.pts2)
    F = estimate_fundamental(
        noisy.pts1, noisy.pts2, noisy.image_size, threshold=1.0, seed=0, final_polish=False
    ).F
    assert noise_truncation(F, data, 1.0) >= LM_MODEL_START
    G = polish_final(F, data, 1.0)
    assert G is not F
    assert abs(np.linalg.det(G / np.linalg.norm(G))) < 1e-12
    assert _cost(G, data, FINAL_TRUNCATION) < _cost(F, data, FINAL_TRUNCATION)
    dF = symmetric_epipolar_distance(F, noisy.pts1, noisy.pts2) < 1.0
    dG = symmetric_epipolar_distance(G, noisy.pts1, noisy.pts2) < 1.0
    assert np.count_nonzero(dG) >= np.count_nonzero(dF)
    lost = dF & ~dG  # an off-plane mask of exactly the matches G loses: F is kept
    assert lost.any()
    assert polish_final(F, data, 1.0, off_plane=lost) is F
    assert np.array_equal(polish_final(F, data, 1.0, off_plane=dG), G)


def _few_true_matches_and_near_misses(seed: int):
    """25 true matches (0.2 px noise), 40 uniform wrong ones, and 25 wrong ones 1.2-2.6 px off
    their true epipolar lines, all on one side: within a 3 px threshold of the true F, where they
    pull a fit truncated at 3 px off it. Returns (pts1, pts2, true mask, F)."""
    sp = make_pair(n_inliers=25, n_outliers=40, noise=0.2, seed=seed)
    rng = np.random.default_rng(seed)
    k = 25
    w, h = sp.image_size
    x1 = np.column_stack([rng.uniform(0, w, k), rng.uniform(0, h, k)])
    lines = np.column_stack([x1, np.ones(k)]) @ sp.F.T  # epipolar lines in image 2
    norm = np.linalg.norm(lines[:, :2], axis=1, keepdims=True)
    p = np.column_stack([rng.uniform(0, w, k), rng.uniform(0, h, k)])
    foot = p - ((p * lines[:, :2]).sum(1, keepdims=True) + lines[:, 2:]) / norm * (
        lines[:, :2] / norm
    )
    x2 = foot + rng.uniform(1.2, 2.6, (k, 1)) * lines[:, :2] / norm
    true = np.concatenate([sp.is_inlier, np.zeros(k, dtype=bool)])
    return np.vstack([sp.pts1, x1]), np.vstack([sp.pts2, x2]), true, sp.F


@pytest.mark.parametrize("seed", range(4))
def test_final_polish_at_a_wide_threshold_follows_the_true_matches(seed):
    """At a 3 px threshold (WIDE_TRUNCATION x 3 px >= WIDE_MIN_PX) polish_final refines F at
    1 px and keeps the refined model by its multi-scale cost: from the 3 px-truncated optimum,
    which the near misses pull off, the true matches' median error falls by a third or more."""
    pts1, pts2, true, F_true = _few_true_matches_and_near_misses(seed)
    assert WIDE_TRUNCATION * 3.0 >= WIDE_MIN_PX > WIDE_TRUNCATION * 1.0
    data = Correspondences.from_pixels(pts1, pts2)
    F = refine_truncated(F_true, data, 3.0)
    G = polish_final(F, data, 3.0)
    assert G is not F
    scales = np.array([1.0, 1.5, 3.0])
    assert (
        multi_scale_cost(np.stack([G]), data, scales)[0]
        < multi_scale_cost(np.stack([F]), data, scales)[0]
    )

    def err(M):
        return np.median(symmetric_epipolar_distance(M, pts1, pts2)[true])

    assert err(G) < 0.67 * err(F), (err(G), err(F))
    assert err(G) < 1.5 * err(F_true)


def test_multi_scale_cost_is_the_sum_of_normalised_msac_costs():
    sp = make_pair(n_inliers=60, n_outliers=30, noise=0.5, seed=1)
    data = Correspondences.from_pixels(sp.pts1, sp.pts2)
    models = np.stack(
        [sp.F / np.linalg.norm(sp.F), _perturbed(sp.F, np.random.default_rng(0), 1e-3)]
    )
    d = symmetric_epipolar_distance(models, sp.pts1, sp.pts2)
    expected = sum(np.minimum(d * d, t * t).sum(axis=1) / (t * t) for t in (0.5, 1.0, 2.0))
    assert np.allclose(multi_scale_cost(models, data, np.array([0.5, 1.0, 2.0])), expected)
    assert (
        multi_scale_cost(models, data, np.array([1.0]))[0]
        < multi_scale_cost(models, data, np.array([1.0]))[1]
    )


@pytest.mark.parametrize("noise", [0.5, 0.8])
def test_final_polish_fits_the_true_matches_of_noisy_pairs_closer(noise):
    """With noise at about the threshold, the estimator's final polish (option final_polish)
    raises the mean squared symmetric epipolar distance of the true matches (capped at 5 px) by
    at most 2 % in any of 8 scenes, lowers it in half of them or more and lowers it on average;
    on precise matches it leaves the estimate as it is.

    The search runs at a fixed cap of 10,000 samples: the automatic cap of these 246 matches
    (40,650) stretches PROSAC's schedule, so each scene starts the polish from another model
    (at noise 0.8, 3 of 8 scenes lower, mean ratio 0.988); the polish is what is tested."""
    lower, ratios = 0, []
    for seed in range(8):
        pair = make_pair(n_inliers=150, n_outliers=60, n_lines=3, noise=noise, seed=seed)
        err = []
        for final_polish in (True, False):
            est = estimate_fundamental(
                pair.pts1, pair.pts2, pair.image_size, threshold=1.0, seed=seed,
                final_polish=final_polish, max_samples=10000,
            )  # fmt: skip
            assert est.status == "ok"
            d = symmetric_epipolar_distance(est.F, pair.pts1, pair.pts2)[pair.is_inlier]
            err.append(np.mean(np.minimum(d, 5.0) ** 2))
        assert err[0] <= 1.02 * err[1], (seed, err)
        lower += err[0] < err[1]
        ratios.append(err[0] / err[1])
    assert lower >= 4
    assert np.mean(ratios) < 1.0
    pair = make_pair(n_inliers=150, n_outliers=60, n_lines=3, noise=0.05, seed=1)
    a, b = (
        estimate_fundamental(pair.pts1, pair.pts2, pair.image_size, seed=1, final_polish=fp)
        for fp in (True, False)
    )
    assert np.array_equal(a.F, b.F)
