"""The paper's escape (``separable.escape``): the decision on numbers, and the separable method
skipping its line search on a clean pair (the answer is then standard RANSAC's, to the bit, with
the probe's local optimisations left out) while running it on a pair with many outliers, whose
probe scores minimal-sample models only."""

from __future__ import annotations

import numpy as np
import pytest
from test_degeneracy import SIZE, planar_majority_pair

from sepfm_ros.geometry import estimate_fundamental, symmetric_epipolar_distance
from sepfm_ros.geometry.robust.trials import ransac_trials
from sepfm_ros.geometry.separable.escape import (
    LINE_SEARCH_HYPOTHESES,
    MODELS_PER_SAMPLE,
    PROBE_SAMPLES,
    copy_generator,
    escape_costs,
    line_search_pays,
)
from sepfm_ros.geometry.synthetic import make_pair


def test_costs_are_the_papers_trial_counts():
    # w = 0.5, p = 0.99: F(3) = 35, F(4) = 72, F(7) = 588 (the paper's Fig. 2 at r = 0.5)
    assert [ransac_trials(k, 0.5) for k in (3, 4, 7)] == [35, 72, 588]
    costs = escape_costs(0.5, 7, 0.99, line_search_hypotheses=40.0, models_per_sample=1.5)
    assert costs.separable == pytest.approx(35 + 1.5 * 72 + 40.0)
    assert costs.standard == pytest.approx(1.5 * 588)
    # the eight-point variant: F(3) + F(5) against F(8)
    costs8 = escape_costs(0.5, 8, 0.99, line_search_hypotheses=0.0, models_per_sample=1.0)
    assert costs8 == (35 + ransac_trials(5, 0.5), ransac_trials(8, 0.5))


def test_the_line_search_pays_at_half_outliers_and_not_on_a_clean_pair():
    assert line_search_pays(0.5, 7, 0.99)  # 183 against 882 hypotheses
    assert line_search_pays(0.2, 7, 0.99)
    # w = 0.9: F(3) = 4, F(4) = 5, F(7) = 8: 4 + 7.5 + 40 against 12
    assert not line_search_pays(0.9, 7, 0.99)
    assert not line_search_pays(1.0, 7, 0.99)
    # a free line search pays at w = 0.9 (11.5 < 12); at w = 1 every count is 1: a tie, and a
    # tie goes to standard RANSAC
    assert line_search_pays(0.9, 7, 0.99, line_search_hypotheses=0.0)
    assert not line_search_pays(1.0, 7, 0.99, line_search_hypotheses=0.0, models_per_sample=2.0)


def test_no_model_seen_keeps_the_line_search():
    # w = 0: every F(k, r) is infinite; as w -> 0 F(7, r) outgrows F(3, r) + F(4, r)
    assert line_search_pays(0.0, 7, 0.99)
    assert line_search_pays(1e-60, 7, 0.99)  # w^7 underflows, w^3 does not


def test_one_break_even_ratio():
    """Below one inlier ratio the line search pays, above it it does not (no flapping)."""
    ratios = np.linspace(0.01, 1.0, 100)
    pays = [line_search_pays(float(w), 7, 0.99) for w in ratios]
    assert pays[0] and not pays[-1]
    switch = int(np.argmin(pays))
    assert all(pays[:switch]) and not any(pays[switch:])
    # with the defaults the switch lies between 0.6 and 0.85 inliers
    assert 0.6 < ratios[switch] < 0.85
    assert LINE_SEARCH_HYPOTHESES > 0 and MODELS_PER_SAMPLE >= 1


@pytest.mark.parametrize("bad", [(-0.1, 7), (1.5, 7), (float("nan"), 7), (0.5, 6)], ids=str)
def test_bad_arguments_raise(bad):
    with pytest.raises(ValueError):
        escape_costs(bad[0], bad[1], 0.99)


def test_copy_generator_draws_and_spawns_the_same_and_leaves_the_original():
    rng = np.random.default_rng(7)
    rng.integers(0, 10, 3)
    rng.spawn(2)
    copy = copy_generator(rng)
    assert np.array_equal(copy.integers(0, 2**31, 5), rng.integers(0, 2**31, 5))
    # its children are the original's (the final model's steps draw on spawned streams)
    assert np.array_equal(copy.spawn(1)[0].random(3), rng.spawn(1)[0].random(3))
    copy.random(10)  # the copy's draws and spawns do not advance the original
    copy.spawn(3)
    again = copy_generator(rng)
    assert np.array_equal(again.random(4), rng.random(4))
    assert np.array_equal(again.spawn(1)[0].random(3), rng.spawn(1)[0].random(3))


def test_an_escaped_estimate_is_deterministic():
    """Same seed, same answer, to the bit: the inner sampling and the significance test draw on
    streams spawned from the escape's copy of the generator."""
    sp = _pair(200, 8, 1)
    a, b = (estimate_fundamental(sp.pts1, sp.pts2, sp.image_size, seed=5) for _ in range(2))
    assert a.line_search_skipped and b.line_search_skipped
    np.testing.assert_array_equal(a.F, b.F)
    assert a.log10_nfa == b.log10_nfa and a.hypotheses == b.hypotheses


def _pair(n_inliers: int, n_outliers: int, seed: int):
    return make_pair(n_inliers=n_inliers, n_outliers=n_outliers, n_lines=3, noise=0.5, seed=seed)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_clean_pair_escapes_to_standard_ransac(seed):
    sp = _pair(200, 8, seed)
    est = estimate_fundamental(sp.pts1, sp.pts2, sp.image_size, method="sep4", seed=seed)
    assert est.ok and est.line_search_skipped
    assert not est.fallback  # no line pair was looked for: not "none found"
    assert est.line_pair is None and est.stage1_hypotheses == 0
    assert "lines" not in est.timings_ms
    # the probe is the start of standard RANSAC's loop, drawn from the same generator: the
    # answer is ransac7's own and its samples too; the probe optimised only its best model
    # locally, where ransac7 optimises each new best, so it scored fewer models
    r7 = estimate_fundamental(sp.pts1, sp.pts2, sp.image_size, method="ransac7", seed=seed)
    np.testing.assert_array_equal(est.F, r7.F)
    np.testing.assert_array_equal(est.inliers, r7.inliers)
    assert est.samples == r7.samples
    assert est.hypotheses < r7.hypotheses
    # without the escape the line search runs on the same pair
    off = estimate_fundamental(
        sp.pts1, sp.pts2, sp.image_size, method="sep4", seed=seed, line_search_escape=False
    )
    assert not off.line_search_skipped and "lines" in off.timings_ms


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_pair_with_many_outliers_runs_the_line_search(seed):
    sp = _pair(80, 160, seed)  # 116 true matches of 276 (36 on the lines): 58% outliers
    est = estimate_fundamental(sp.pts1, sp.pts2, sp.image_size, method="sep4", seed=seed)
    assert est.ok and not est.line_search_skipped
    assert est.line_pair is not None and est.stage1_hypotheses > 0
    assert "lines" in est.timings_ms and "probe" in est.timings_ms
    # the probe's models count: more than with the escape off, whose draws stage 2 repeats;
    # far below PROBE_LO_GAIN x the break-even, the probe scored minimal-sample models only
    # (its PROBE_SAMPLES samples, up to 3 roots each), no local optimisation
    off = estimate_fundamental(
        sp.pts1, sp.pts2, sp.image_size, method="sep4", seed=seed, line_search_escape=False
    )
    np.testing.assert_array_equal(est.F, off.F)
    assert est.samples == off.samples + PROBE_SAMPLES
    assert off.hypotheses < est.hypotheses <= off.hypotheses + 3 * PROBE_SAMPLES


def test_an_expensive_line_search_is_skipped_even_with_outliers():
    sp = _pair(80, 160, 1)
    est = estimate_fundamental(
        sp.pts1, sp.pts2, sp.image_size, method="sep4", seed=1, line_search_cost=1e12
    )
    assert est.ok and est.line_search_skipped and est.line_pair is None


def test_the_lmeds_methods_keep_their_line_search():
    sp = _pair(200, 8, 1)
    est = estimate_fundamental(sp.pts1, sp.pts2, sp.image_size, method="sep4-lmeds", seed=1)
    assert not est.line_search_skipped and "lines" in est.timings_ms


def test_bad_line_search_cost_raises():
    sp = _pair(40, 0, 1)
    with pytest.raises(ValueError, match="line_search_cost must be >= 0"):
        estimate_fundamental(sp.pts1, sp.pts2, sp.image_size, line_search_cost=-1.0)


@pytest.mark.parametrize(("seed", "escaped"), [(4, True), (0, False), (22, True)])
def test_a_dominant_plane_gets_the_line_search_after_all(seed, escaped):
    """A plane holding most matches can show the probe a high inlier ratio; the escape then
    hands the pair to standard RANSAC, which stops on the plane (degenerate), and sep4 runs its
    line search as without the escape (same answer, the first try's work counted: seeds 4 and
    22). On seed 0 the probe's best minimal model holds too few matches and the line search
    runs at once. On seed 4 the line search finds the F of the 10 off-plane matches."""
    pts1, pts2, off1, off2, _ = planar_majority_pair(n_off=10, n_out=30, seed=seed)
    r7 = estimate_fundamental(pts1, pts2, SIZE, seed=seed, method="ransac7")
    assert r7.status.startswith("degenerate: dominant plane")
    est = estimate_fundamental(pts1, pts2, SIZE, seed=seed)
    off = estimate_fundamental(pts1, pts2, SIZE, seed=seed, line_search_escape=False)
    assert ("escape" in est.timings_ms) == escaped and not est.line_search_skipped
    assert est.line_pair is not None and est.status == off.status
    np.testing.assert_array_equal(est.F, off.F)
    # the first try's (or the probe's) samples and models count on top of the line search's
    first = PROBE_SAMPLES + 1 if escaped else PROBE_SAMPLES
    assert est.samples >= off.samples + first and est.hypotheses > off.hypotheses
    if seed == 4:
        assert est.ok and np.median(symmetric_epipolar_distance(est.F, off1, off2)) < 1.0
