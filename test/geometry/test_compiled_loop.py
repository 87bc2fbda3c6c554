"""The compiled loop (fundamental/compiled_loop.py) against the generic Python rounds of
robust/loop.py: the same run to the bit, whichever way it is split into calls, for one arm and for
a race of arms with fixed points that join on the schedule and are dropped."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from sepfm_ros.geometry.fundamental.compiled_loop import CompiledLoop
from sepfm_ros.geometry.fundamental.correspondences import Correspondences
from sepfm_ros.geometry.fundamental.problem import FundamentalProblem
from sepfm_ros.geometry.robust.loop import Budget, Loop, make_loop
from sepfm_ros.geometry.robust.options import RaceOptions, SamplingOptions
from sepfm_ros.geometry.synthetic import make_pair

SHARED = Path(__file__).resolve().parents[3] / "shared" / "data"
LINES = SHARED.parent / "data_lines"


def _data(seed: int, outliers: int, noise: float) -> Correspondences:
    pair = make_pair(n_inliers=150, n_outliers=outliers, noise=noise, seed=seed)
    return Correspondences.from_pixels(pair.pts1, pair.pts2)


def _loop(cls: type[Loop], data: Correspondences, seed: int, **kw: object) -> Loop:
    solver = kw.pop("solver", "seven")
    lo = kw.pop("lo", "lm")
    oriented = kw.pop("oriented", False)
    spread = kw.pop("spread", 0)
    initial = kw.pop("initial", None)
    limit = int(kw.pop("limit", 2000))
    sampling = SamplingOptions(**kw)  # type: ignore[arg-type]
    lo_data = data.spread(spread) if spread else None
    problem = FundamentalProblem(
        data, solver, 1.0, "msac", lo=lo, lo_data=lo_data, oriented=oriented
    )
    return make_loop(
        [problem], np.random.default_rng(seed), 0.99, limit, budget=Budget(limit),
        sampling=sampling, initial=initial, cls=cls,
    )  # fmt: skip


def _state(loop: Loop) -> tuple[object, ...]:
    """Everything a run leaves behind: the best and the arm's models, counts and costs, the
    SPRT's counters, the budget, and the generator's next draw."""
    arm, best, sprt = loop.arms[0], loop.best, loop.sprt
    sprt_state = (
        None
        if sprt is None
        else (sprt.delta, sprt.epsilon, sprt.A, sprt.rej_inliers, sprt.rej_read, sprt.models,
              sprt.samples, sprt.points_read, sprt.rejected)
    )  # fmt: skip
    models = tuple(
        None if m is None else np.asarray(m).tobytes()
        for m in (best.model, arm.model, arm.top_model)
    )
    return (
        models, best.cost, best.count, best.leader, arm.cost, arm.top_cost, arm.samples,
        arm.best_count, arm.raw_count, loop.hypotheses, loop.extra_lo, loop.budget.used,
        sprt_state, None if arm.sampler is None else arm.sampler.t, loop.rng.random(),
    )  # fmt: skip


CONFIGS = [
    dict(prosac=True, sprt=True, bailout=True),  # the default method's
    dict(prosac=True, sprt=True, bailout=True, spread=60),
    dict(prosac=True, sprt=False, bailout=True, lo="sampson"),
    dict(prosac=False, sprt=True, bailout=False, lo="plain"),
    dict(prosac=False, sprt=False, bailout=False, oriented=True),
    dict(prosac=True, sprt=True, bailout=True, solver="eight"),
    dict(prosac=True, sprt=True, bailout=True, limit=40),  # the budget ends the run
]


@pytest.mark.parametrize("config", range(len(CONFIGS)))
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_compiled_run_equals_python_rounds(config: int, seed: int) -> None:
    data = _data(seed, outliers=[50, 150, 400][seed], noise=[0.3, 1.0, 0.5][seed])
    a = _loop(Loop, data, seed, **CONFIGS[config])
    b = _loop(CompiledLoop, data, seed, **CONFIGS[config])
    assert isinstance(b, CompiledLoop) and b.compiled()
    ra, rb = a.run(), b.run()
    assert _state(a) == _state(b)
    assert (ra.cost, ra.count, ra.hypotheses, ra.samples, ra.converged, ra.points_read) == (
        rb.cost, rb.count, rb.hypotheses, rb.samples, rb.converged, rb.points_read,
    )  # fmt: skip
    assert np.array_equal(ra.model, rb.model)


@pytest.mark.parametrize("seed", [0, 3])
def test_compiled_probe_resume_run_equals_python(seed: int) -> None:
    """The escape's split: a probe without local optimisation, one local optimisation, then the
    rest of the run; and a run that starts from an earlier model (the fallback's)."""
    data = _data(seed, outliers=300, noise=0.5)
    a, b = (
        _loop(c, data, seed, prosac=True, sprt=True, bailout=True) for c in (Loop, CompiledLoop)
    )
    assert a.start(8) == b.start(8)
    assert _state(a) == _state(b)
    a.resume(), b.resume()
    assert _state(a) == _state(b)
    ra, rb = a.run(), b.run()
    assert np.array_equal(ra.model, rb.model) and ra.hypotheses == rb.hypotheses
    initial = (ra.model, ra.cost * 1.5, ra.count - 5)
    a, b = (
        _loop(c, data, seed + 1, prosac=True, sprt=True, bailout=True, initial=initial)
        for c in (Loop, CompiledLoop)
    )
    ra, rb = a.run(), b.run()
    assert _state(a) == _state(b) and np.array_equal(ra.model, rb.model)


def test_compiled_loop_runs_python_rounds_for_other_arms() -> None:
    """LMedS scoring (or fixed points, or a race) is not compiled: the generic rounds run."""
    data = _data(0, outliers=50, noise=0.3)
    problem = FundamentalProblem(data, "seven", 1.0, "lmeds")
    loop = make_loop([problem], np.random.default_rng(0), 0.99, 300, cls=CompiledLoop)
    assert isinstance(loop, CompiledLoop) and not loop.compiled()
    assert loop.run().model is not None
    empty = make_loop(iter([]), np.random.default_rng(0), 0.99, 300, cls=CompiledLoop)
    assert not empty.compiled()  # no arm joined (no line pair gave a stage-2 arm)
    result = empty.run()
    assert result.model is None and result.samples == [] and not result.converged


@pytest.mark.skipif(not (SHARED / "pairs.json").exists(), reason="needs ../shared/data")
def test_compiled_loop_on_real_pairs_matches_python_rounds(tmp_path: Path) -> None:
    """Real matches (four shared pairs, SIFT at ratio 0.8, best first) in the default method's
    configuration."""
    from sepfm_ros.evaluation.manifest import load_manifest
    from sepfm_ros.evaluation.matches_cache import MatchesCache, MatchSettings

    pairs, _ = load_manifest(SHARED / "pairs.json")
    cache = MatchesCache(tmp_path, MatchSettings("sift", 0.8))
    for pair in pairs[:: max(1, len(pairs) // 4)][:4]:
        m = cache.matches(pair)
        data = Correspondences.from_pixels(m.pts_a, m.pts_b)
        a, b = (
            _loop(c, data, 0, prosac=True, sprt=True, bailout=True, limit=5000)
            for c in (Loop, CompiledLoop)
        )
        ra, rb = a.run(), b.run()
        assert ra.hypotheses > 0
        assert _state(a) == _state(b) and np.array_equal(ra.model, rb.model)


def _race_arms(data: Correspondences, pair_seed: int, wrong: int) -> list[FundamentalProblem]:
    """Stage-2-like arms: three fixed correspondences each (true ones, or ``wrong`` arms of
    wrong ones, whose fixed-point check fails), pools without them, then an arm without fixed
    points at a quarter share of the samples."""
    rng = np.random.default_rng(pair_seed)
    n = len(data)
    arms = []
    for j in range(4):
        pick = rng.choice(n, 3, replace=False)
        f1, f2 = data.pts1[pick], data.pts2[pick].copy()
        if j < wrong:
            f2 = f2[::-1].copy()  # three wrong correspondences
        pool = np.setdiff1d(np.arange(n), pick)
        arms.append(
            FundamentalProblem(data, "seven", 1.0, "msac", f1, f2, pool=pool, fixed_tol=1.5)
        )
    arms.append(FundamentalProblem(data, "seven", 1.0, "msac", race_share=0.25))
    return arms


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_compiled_race_equals_python_rounds(seed: int) -> None:
    """A race as the separable method runs it: arms built lazily as they join on the schedule,
    arms with wrong fixed points dropped, lagging arms dropped after a local optimisation, the
    unfixed arm held to its share; every arm's state, the drops and the draws agree."""
    pair = make_pair(n_inliers=120, n_outliers=[60, 200, 120, 300][seed], noise=0.5, seed=seed)
    # inliers first so that the arms' fixed points are true matches (PROSAC: best first)
    data = Correspondences.from_pixels(pair.pts1, pair.pts2)
    runs = []
    for cls in (Loop, CompiledLoop):
        arms = _race_arms(data, seed, wrong=[1, 2, 0, 1][seed])
        built: list[int] = []

        def lazily(arms: list[FundamentalProblem] = arms, built: list[int] = built):
            for arm in arms:
                built.append(1)  # built only when it joins
                yield arm

        loop = make_loop(
            lazily(), np.random.default_rng(seed), 0.99, 3000, budget=Budget(3000),
            race=RaceOptions(pool_rule="support", add_after=(20, 40)),
            sampling=SamplingOptions(prosac=True, sprt=True, bailout=True), cls=cls,
        )  # fmt: skip
        result = loop.run()
        runs.append((loop, result, len(built)))
    (a, ra, na), (b, rb, nb) = runs
    assert isinstance(b, CompiledLoop) and b.compiled()
    assert len(a.arms) > 1 and na == nb
    assert (ra.samples, ra.dropped, ra.leader, ra.converged, ra.hypotheses) == (
        rb.samples, rb.dropped, rb.leader, rb.converged, rb.hypotheses,
    )  # fmt: skip
    assert np.array_equal(ra.model, rb.model) and ra.cost == rb.cost
    for x, y in zip(a.arms, b.arms, strict=True):
        assert (x.samples, x.best_count, x.raw_count, x.cost, x.top_cost, x.checked) == (
            y.samples, y.best_count, y.raw_count, y.cost, y.top_cost, y.checked,
        )  # fmt: skip
    assert a.race.active == b.race.active and a.rng.random() == b.rng.random()


def test_compiled_races_drop_arms() -> None:
    """The race test above exercises drops (it would pass vacuously without them)."""
    pair = make_pair(n_inliers=120, n_outliers=200, noise=0.5, seed=1)
    data = Correspondences.from_pixels(pair.pts1, pair.pts2)
    loop = make_loop(
        iter(_race_arms(data, 1, wrong=2)), np.random.default_rng(1), 0.99, 3000,
        budget=Budget(3000), race=RaceOptions(pool_rule="support", add_after=(20, 40)),
        sampling=SamplingOptions(prosac=True, sprt=True, bailout=True), cls=CompiledLoop,
    )  # fmt: skip
    result = loop.run()
    assert len(loop.arms) >= 3 and len(result.dropped) >= 1


@pytest.mark.skipif(not (LINES / "pairs.json").exists(), reason="needs ../shared/data_lines")
def test_estimates_on_line_rich_pairs_equal_python_rounds(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The default method end to end on line-rich pairs (SIFT 0.95, the escape, the line
    search, stage 2's race and the fallback): the same estimate with the compiled rounds as
    with the Python ones."""
    from sepfm_ros.evaluation.manifest import load_manifest
    from sepfm_ros.evaluation.matches_cache import MatchesCache, MatchSettings
    from sepfm_ros.geometry import estimate_fundamental

    pairs, _ = load_manifest(LINES / "pairs.json")
    cache = MatchesCache(tmp_path, MatchSettings("sift", 0.95))
    raced = 0
    for pair in pairs[:: len(pairs) // 3][:3]:
        m = cache.matches(pair)
        results = []
        for compiled in (True, False):
            if not compiled:
                monkeypatch.setattr(CompiledLoop, "compiled", lambda self: False)
            results.append(
                estimate_fundamental(m.pts_a, m.pts_b, m.size_a, m.size_b, seed=0, threshold=1.0)
            )
            monkeypatch.undo()
        e, p = results
        assert np.array_equal(e.F, p.F) and np.array_equal(e.inliers, p.inliers)
        assert (e.hypotheses, e.line_pair, e.line_search_skipped, e.fallback, e.status) == (
            p.hypotheses, p.line_pair, p.line_search_skipped, p.fallback, p.status,
        )  # fmt: skip
        raced += not e.line_search_skipped
    assert raced >= 1
