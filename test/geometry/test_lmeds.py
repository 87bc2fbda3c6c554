"""The LMedS methods (``lmeds7``, ``lmeds8``, ``sep4-lmeds``, ``sep5-lmeds``) are least median of
squares: model by the median residual, inliers and scale from the robust scale, the classic
F(k, 0.5) sample floor, and a status that is not "ok" beyond the breakdown point."""

from __future__ import annotations

import numpy as np
import pytest

from sepfm_ros.evaluation.methods import REGISTRY, resolve_methods
from sepfm_ros.geometry import METHODS, estimate_fundamental, normalize_fundamental
from sepfm_ros.geometry.epipolar import msac_kernel, symmetric_epipolar_distance
from sepfm_ros.geometry.fundamental import final as final_module
from sepfm_ros.geometry.fundamental.correspondences import Correspondences
from sepfm_ros.geometry.fundamental.problem import FundamentalProblem
from sepfm_ros.geometry.fundamental.refine import lmeds_refit
from sepfm_ros.geometry.robust.lmeds import lmeds_final_inliers, robust_scale
from sepfm_ros.geometry.robust.trials import ransac_trials
from sepfm_ros.geometry.synthetic import make_pair

LMEDS = ["lmeds7", "lmeds8", "sep4-lmeds", "sep5-lmeds"]


def _median_sq(F: np.ndarray, pts1: np.ndarray, pts2: np.ndarray) -> float:
    return float(np.median(symmetric_epipolar_distance(F, pts1, pts2) ** 2))


def test_lmeds8_is_a_method_of_the_estimator_and_of_the_evaluation():
    assert "lmeds8" in METHODS and "lmeds8" in REGISTRY
    assert [m.name for m in resolve_methods("lmeds8")] == ["lmeds8"]
    sp = make_pair(n_inliers=100, n_outliers=40, n_lines=2, noise=0.3, seed=4)
    est = estimate_fundamental(sp.pts1, sp.pts2, sp.image_size, method="lmeds8", seed=0)
    assert est.ok and est.method == "lmeds8" and est.scale is not None
    assert est.stage1_hypotheses == 0 and est.line_pair is None


def _check_robust_scale_and_inliers(method: str, scene: int, seed: int) -> None:
    # 120 general + 3 x 12 line points, 100 outliers (39 %), 0.5 px noise per coordinate
    noise = 0.5
    sp = make_pair(n_inliers=120, n_outliers=100, n_lines=3, noise=noise, seed=scene)
    # the threshold is far too large for the data: an LMedS method must not depend on it
    est = estimate_fundamental(
        sp.pts1, sp.pts2, sp.image_size, method=method, threshold=8.0, seed=seed
    )
    assert est.status == "ok"
    true_d = symmetric_epipolar_distance(sp.F, sp.pts1, sp.pts2)[sp.is_inlier]
    true_scale = float(np.sqrt(np.mean(true_d**2)))  # RMS symmetric distance of true matches
    assert abs(est.scale - true_scale) <= 0.3 * true_scale, (est.scale, true_scale)
    recovered = np.count_nonzero(est.inliers & sp.is_inlier) / np.count_nonzero(sp.is_inlier)
    false = np.count_nonzero(est.inliers & ~sp.is_inlier) / est.num_inliers
    assert recovered >= 0.9 and false <= 0.05, (recovered, false)
    # the inliers are those within 2.5 robust scales of the final F, not within the threshold
    d = symmetric_epipolar_distance(est.F, sp.pts1, sp.pts2)
    assert np.array_equal(est.inliers, d < 2.5 * est.scale)
    assert np.count_nonzero(d < 8.0) > est.num_inliers


@pytest.mark.parametrize(
    "method, scene", [(m, s) for m in LMEDS for s in (3, 9) if (m, s) != ("sep4-lmeds", 3)]
)
def test_robust_scale_and_inliers_match_the_truth(method, scene):
    _check_robust_scale_and_inliers(method, scene, scene + 100)


# sep4-lmeds on scene 3: the line pair's triple holds a match 1.7 px off the true F (2.2 robust
# scales), which every model of that arm passes through exactly; the least-median model and its
# refits keep the bias (the scale is off by more than 30 % on most of seeds 103-112, with status
# still "ok" at the 8 px threshold). A known weakness of the fixed-triple LMedS method, kept
# visible here over ten seeds (one seed's pass or fail depends on the random stream): the day
# every seed passes, this strict xfail fails and the case joins the test above.
@pytest.mark.xfail(
    strict=True, reason="sep4-lmeds: a noisy fixed line point biases the least-median model"
)
def test_sep4_lmeds_with_a_noisy_fixed_line_point():
    for seed in range(103, 113):
        _check_robust_scale_and_inliers("sep4-lmeds", 3, seed)


def test_final_scale_is_the_reweighted_robust_scale():
    rng = np.random.default_rng(0)
    d = np.abs(np.concatenate([rng.normal(0, 1.0, 600), rng.uniform(20, 200, 400)]))
    inliers, sigma, med = lmeds_final_inliers(d, 7)
    assert med == pytest.approx(np.median(d**2))
    s0 = robust_scale(med, len(d), 7)
    assert s0 > 1.3  # the median-based scale is inflated by the 40 % outliers
    assert sigma == pytest.approx(1.0, rel=0.1)
    assert inliers[:600].mean() > 0.98 and not inliers[600:].any()


def _two_models(seed: int):
    """Matches on which F_a fits 55 % exactly and leaves 45 % 5 px off, while F_b leaves every
    match within about a pixel: the median prefers F_a, the MSAC cost at 1 px prefers F_b."""
    rng = np.random.default_rng(seed)
    Fa = normalize_fundamental(make_pair(n_inliers=20, seed=seed).F)
    Fb = normalize_fundamental(make_pair(n_inliers=20, seed=seed + 1).F)
    pts1, pts2 = [], []
    while len(pts1) < 200:
        x1 = rng.uniform([0, 0], [640, 480])
        la, lb = Fa @ [*x1, 1.0], Fb @ [*x1, 1.0]
        la, lb = la / np.hypot(*la[:2]), lb / np.hypot(*lb[:2])
        p = np.cross(la, lb)
        if abs(p[2]) < 1e-12:
            continue
        p = p[:2] / p[2]
        if not (-200 < p[0] < 840 and -200 < p[1] < 680):
            continue
        ua, ub = np.array([-la[1], la[0]]), np.array([-lb[1], lb[0]])
        sin = abs(ua @ lb[:2])
        if sin < 0.2:
            continue
        on_a = len(pts1) < 110  # 55 % on F_a's line, 0.3 px off F_b's line
        x2 = p + (0.3 / sin) * ua if on_a else p + (5.0 / sin) * ub
        pts1.append(x1)
        pts2.append(x2)
    return Fa, Fb, np.array(pts1), np.array(pts2)


def test_lmeds_selects_by_median_where_msac_would_not(monkeypatch):
    Fa, Fb, pts1, pts2 = _two_models(2)
    data = Correspondences.from_pixels(pts1, pts2)
    models = np.ascontiguousarray(np.stack([Fa, Fb]))
    msac, _ = msac_kernel(models, data.X1, data.X2, 1.0)
    assert msac[1] < msac[0]  # the crafted case: MSAC prefers F_b ...
    assert _median_sq(Fa, pts1, pts2) < _median_sq(Fb, pts1, pts2)  # ... LMedS F_a
    cost, _ = FundamentalProblem(data, "eight", 1.0, "lmeds").score(models)
    assert int(np.argmin(cost)) == 0
    cost, _ = FundamentalProblem(data, "eight", 1.0, "msac").score(models)
    assert int(np.argmin(cost)) == 1
    # the final model: a refit candidate (here F_b) replaces F only by a lower median
    monkeypatch.setattr(final_module, "lmeds_refit", lambda *a, **k: Fb[None])
    F, refits = final_module._final_model_lmeds(Fa, data, 8, True)
    assert refits == 1 and np.allclose(F, Fa)
    monkeypatch.setattr(final_module, "iterative_refit", lambda *a, **k: Fb[None])
    F, _ = final_module._final_model(Fa, data, 1.0, True)
    assert np.allclose(F, Fb)  # where MSAC's final step would take F_b


@pytest.mark.parametrize("method", LMEDS)
def test_returned_model_has_the_lowest_median_of_its_refit_candidates(method):
    sp = make_pair(n_inliers=120, n_outliers=80, n_lines=3, noise=0.7, seed=6)
    est = estimate_fundamental(
        sp.pts1, sp.pts2, sp.image_size, method=method, threshold=2.0, seed=3
    )
    assert est.status == "ok"
    data = Correspondences.from_pixels(sp.pts1, sp.pts2)
    p = 7 if method in ("lmeds7", "sep4-lmeds") else 8
    candidates = [*lmeds_refit(est.F, data, p, irls_iterations=0), *lmeds_refit(est.F, data, p)]
    assert candidates
    med = _median_sq(est.F, sp.pts1, sp.pts2)
    # a further refit may improve the median slightly, never by much (the final step kept the
    # lowest median of its candidates)
    for G in candidates:
        assert med <= 1.05 * _median_sq(G, sp.pts1, sp.pts2)


@pytest.mark.parametrize("method", ["lmeds7", "lmeds8"])
def test_lmeds_draws_at_least_f_k_one_half_samples(method):
    # noise-free, no outliers: adaptive RANSAC would stop after one sample; LMedS keeps the
    # classic floor F(k, 0.5) since its robust inlier count cannot tell a wrong model apart
    sp = make_pair(n_inliers=100, n_outliers=0, n_lines=2, noise=0.0, seed=1)
    est = estimate_fundamental(sp.pts1, sp.pts2, sp.image_size, method=method, seed=0)
    assert est.ok and est.inliers.all()
    k = 7 if method == "lmeds7" else 8
    assert est.stage2_hypotheses >= 0.9 * ransac_trials(k, 0.5, 0.99)
    capped = estimate_fundamental(
        sp.pts1, sp.pts2, sp.image_size, method=method, seed=0, max_samples=50
    )
    assert capped.ok and capped.stage2_hypotheses < 200


@pytest.mark.parametrize("method", LMEDS)
@pytest.mark.parametrize("scene", [3, 5])
def test_beyond_half_outliers_is_not_reported_ok_with_a_wrong_F(method, scene):
    # 156 true matches, 300 outliers (66 %): beyond LMedS's breakdown point
    sp = make_pair(n_inliers=120, n_outliers=300, n_lines=3, noise=0.5, seed=scene)
    est = estimate_fundamental(
        sp.pts1, sp.pts2, sp.image_size, method=method, threshold=1.5, seed=scene + 100
    )
    recovered = np.count_nonzero(est.inliers & sp.is_inlier) / np.count_nonzero(sp.is_inlier)
    false = np.count_nonzero(est.inliers & ~sp.is_inlier) / max(est.num_inliers, 1)
    if est.status == "ok":
        assert recovered >= 0.9 and false <= 0.05
    else:
        assert not est.ok


def test_noise_above_the_threshold_is_flagged():
    # a robust scale above the threshold: the status says so (LMedS itself needs no threshold)
    sp = make_pair(n_inliers=120, n_outliers=60, n_lines=2, noise=1.5, seed=2)
    est = estimate_fundamental(sp.pts1, sp.pts2, sp.image_size, method="lmeds8", seed=0)
    assert est.F is not None and est.scale > 1.0
    assert est.status.startswith("unreliable: robust scale")


def test_separable_lmeds_races_line_pairs():
    sp = make_pair(n_inliers=120, n_outliers=100, n_lines=3, noise=0.5, seed=5)
    est = estimate_fundamental(sp.pts1, sp.pts2, sp.image_size, method="sep5-lmeds", seed=105)
    assert est.ok and est.line_pair is not None and not est.fallback
    assert est.stage1_hypotheses > 0
    # fewer F hypotheses than the eight-point LMedS baseline
    base = estimate_fundamental(sp.pts1, sp.pts2, sp.image_size, method="lmeds8", seed=105)
    assert est.stage2_hypotheses < 0.5 * base.stage2_hypotheses
