"""Benchmark: the race's pooling rule and the line thresholds of the default method, each
alternative against the default options, same run, same matches, three seeds.

Two choices of the separable estimator are measured here:

- which racing stage-2 arms count their samples toward the pooled F(k, r) stop
  (``EstimatorOptions.race_pool`` / ``race_pool_ratio``, ``RaceOptions.pool_rule`` /
  ``pool_ratio``): by support, arms with at least a share of the best model's inlier count
  (0.8, 0.9, 0.95, 1.0), or by model, arms whose best model holds most of the best model's
  inliers (at least 0.8 / 0.9 of them);
- the stage-1 threshold T1 (``line_threshold``) and the incidence distance C
  (``line_distance``), stated in working px of the ``hough_width`` (512 px) line search, so in
  image px they grow with the image width (x 1241 / 512 on KITTI); the alternatives state them
  in image px (equal to 0.5 and 1.5 working px at 640 px width, or tied to F's 1 px threshold:
  T1 = 0.5 / 1 px, C = 1.5 / 2 / 3 px), or take other working-px values (T1 and C alone too).
  An image-px value v is passed as v * hough_width / image width (every pair here has two
  images of one width, where this is exact).

Sets, threshold 1 px, confidence 0.99:

- ``lines75``, ``lines95``: ../shared/data_lines (line-rich Strecha, 1536x1024) at SIFT ratio
  0.75 and 0.95, ``--max-pairs`` evenly spaced pairs (duplicates dropped, as bench_lines.py);
- ``shared95``: ../shared/data/pairs.json at SIFT ratio 0.95 (every ``--step``-th pair);
- ``kitti``, ``temple``: the node's pairs of bench_node_pairs.py (consecutive frames, ORB 1000,
  ratio 0.8, the node's own matching), pairs with >= 20 GT inliers (all of them when fewer
  than ``--max-pairs``).

Printed per set and configuration: mean F-score, its change against the defaults per seed,
success % (median GT-inlier error < 1 px and >= 20 GT inliers recovered), median hypotheses,
median ms and ms over the defaults' (same run).

    python benchmarks/bench_race_lines.py [--sets lines75,lines95,shared95,kitti,temple]
        [--max-pairs 100] [--step 1] [--seeds 0,1,2] [--configs "label;label"] [--cache DIR]
        [--write-docs [--doc FILE]]

SIFT matches come from the matches cache (``--cache``, default .cache/matches of the checkout).
Figures are measured on this machine in this run; nothing is asserted.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from pathlib import Path

import bench_docs
import numpy as np
from bench_lines import select_pairs
from bench_node_pairs import evaluable, node_pairs

from sepfm_ros.evaluation.manifest import load_manifest
from sepfm_ros.evaluation.matches_cache import MatchesCache, MatchSettings
from sepfm_ros.evaluation.metrics import positives, run_metrics
from sepfm_ros.geometry import DEFAULT_METHOD, estimate_fundamental
from sepfm_ros.geometry.compiled import warm_up as warm_up_geometry
from sepfm_ros.geometry.options import EstimatorOptions

REPO = Path(__file__).resolve().parent.parent
SHARED = REPO.parent / "shared"
SETS = {
    "lines75": ("data_lines", 0.75),
    "lines95": ("data_lines", 0.95),
    "shared95": ("data", 0.95),
    "kitti": ("node", 0.8),
    "temple": ("node", 0.8),
}
_D = EstimatorOptions()
WIDTH = _D.hough_width


def _image_px(t1: float, c: float) -> Callable[[tuple[int, int]], dict]:
    """Options stating T1 and C in image px of an image of the given size."""

    def options(size: tuple[int, int]) -> dict:
        s = WIDTH / size[0]
        return {"line_threshold": t1 * s, "line_distance": c * s}

    return options


def _fixed(**opts) -> Callable[[tuple[int, int]], dict]:
    return lambda size: dict(opts)


#: the default options' configuration (every alternative is compared with it)
CURRENT = (
    f"defaults (pool by {_D.race_pool} {_D.race_pool_ratio:g}; T1 {_D.line_threshold:g}, "
    f"C {_D.line_distance:g} working px)"
)
#: label -> options of one image size; one equal to the defaults is left out of a run
ALTERNATIVES: dict[str, Callable[[tuple[int, int]], dict]] = {
    "pool by support 0.8": _fixed(race_pool="support", race_pool_ratio=0.8),
    "pool by support 0.9": _fixed(race_pool="support", race_pool_ratio=0.9),
    "pool by support 0.95": _fixed(race_pool="support", race_pool_ratio=0.95),
    "pool by support 1.0": _fixed(race_pool="support", race_pool_ratio=1.0),
    "pool by model, 0.8 of the best model's inliers": _fixed(
        race_pool="model", race_pool_ratio=0.8
    ),
    "pool by model, 0.9 of the best model's inliers": _fixed(
        race_pool="model", race_pool_ratio=0.9
    ),
    "T1 0.625, C 1.875 image px (0.5, 1.5 working px at 640 px)": _image_px(0.625, 1.875),
    "T1 0.5, C 1.5 image px (x F's threshold)": _image_px(0.5, 1.5),
    "T1 1, C 2 image px (x F's threshold)": _image_px(1.0, 2.0),
    "T1 1, C 3 image px (x F's threshold)": _image_px(1.0, 3.0),
    "T1 0.5, C 1.5 working px": _fixed(line_threshold=0.5, line_distance=1.5),
    "T1 0.35, C 1.0 working px": _fixed(line_threshold=0.35, line_distance=1.0),
    "T1 0.75, C 2.25 working px": _fixed(line_threshold=0.75, line_distance=2.25),
    "T1 1, C 3 working px": _fixed(line_threshold=1.0, line_distance=3.0),
    "T1 1.5, C 4.5 working px": _fixed(line_threshold=1.5, line_distance=4.5),
    "T1 1.5, C 1.5 working px": _fixed(line_threshold=1.5, line_distance=1.5),
    "T1 0.5, C 4.5 working px": _fixed(line_threshold=0.5, line_distance=4.5),
    "T1 2, C 6 working px": _fixed(line_threshold=2.0, line_distance=6.0),
}
CONFIGS = {CURRENT: _fixed(), **ALTERNATIVES}


def is_default(label: str) -> bool:
    """The configuration's options do not depend on the image size and equal the defaults."""
    opts = CONFIGS[label]((1000, 1000))
    return opts == CONFIGS[label]((500, 500)) and all(getattr(_D, k) == v for k, v in opts.items())


def load_set(name: str, cache_dir: Path, max_pairs: int, step: int) -> tuple[list, str]:
    """[(pair id, pts_a, pts_b, size_a, size_b, positives)] of a set, and which pairs."""
    kind, ratio = SETS[name]
    if kind == "node":
        pairs = [p for p in node_pairs(name, SHARED / "data", max_pairs) if evaluable(p)]
        items = [
            (p.pair_id, p.matches.pts_a, p.matches.pts_b, p.size_a, p.size_b, p.positives)
            for p in pairs
        ]
        return items, (
            f"{len(items)} consecutive pairs with >= 20 GT inliers (at most --max-pairs evenly "
            "spaced ones), node matching: ORB 1000, ratio 0.8"
        )
    manifest = SHARED / kind / "pairs.json"
    pairs, _ = load_manifest(manifest)
    if kind == "data_lines":
        pairs, which = select_pairs(pairs, max_pairs)
    else:
        pairs = pairs[::step]
        which = f"{len(pairs)} pairs (every {step}th of {kind}/pairs.json)"
    cache = MatchesCache(cache_dir, MatchSettings("sift", ratio))
    items = []
    for i, pair in enumerate(pairs):
        m = cache.matches(pair)
        pos = positives(pair.F_gt, m.pts_a, m.pts_b)
        items.append((pair.pair_id, m.pts_a, m.pts_b, m.size_a, m.size_b, pos))
        sys.stderr.write(f"\r  {name}: matches {i + 1}/{len(pairs)}")
    sys.stderr.write("\n")
    return items, f"{which}, SIFT ratio {ratio}"


def run_set(name: str, items: list, configs: list[str], seeds: list[int]) -> dict:
    """{config: {seed: [(ok, f, hypotheses, ms) per pair]}}."""
    rows = {c: {s: [] for s in seeds} for c in configs}
    t0 = time.time()
    for i, (_, pa, pb, sa, sb, pos) in enumerate(items):
        for c in configs:
            opts = CONFIGS[c](sa)
            for seed in seeds:
                t = time.perf_counter()
                e = estimate_fundamental(pa, pb, sa, sb, method=DEFAULT_METHOD, threshold=1.0,
                                         confidence=0.99, seed=seed, **opts)  # fmt: skip
                ms = 1e3 * (time.perf_counter() - t)
                met = run_metrics(e.F, pa, pb, pos, 1.0)
                ok = met.succeeded
                rows[c][seed].append((bool(ok), met.f_score, float(e.hypotheses), ms))
        sys.stderr.write(f"\r  {name}: {i + 1}/{len(items)} pairs, {time.time() - t0:.0f} s")
    sys.stderr.write("\n")
    return rows


def table(rows: dict, seeds: list[int]) -> str:
    base = {s: np.array(rows[CURRENT][s]) for s in seeds}
    base_ms = np.median(np.concatenate([base[s][:, 3] for s in seeds]))
    base_f = [base[s][:, 1].mean() for s in seeds]
    out = [
        "| configuration | F-score | ΔF-score per seed | success % | Δsuccess % per seed | "
        "hypotheses (median) | ms (median) | ms / defaults |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for label, by_seed in rows.items():
        r = {s: np.array(by_seed[s]) for s in seeds}
        allr = np.concatenate([r[s] for s in seeds])
        df = [r[s][:, 1].mean() - base[s][:, 1].mean() for s in seeds]
        ds = [100 * (r[s][:, 0].mean() - base[s][:, 0].mean()) for s in seeds]
        ms = np.median(allr[:, 3])
        out.append(
            f"| {label} | {allr[:, 1].mean():.4f} | "
            + ("—" if label == CURRENT else " / ".join(f"{d:+.4f}" for d in df))
            + f" | {100 * allr[:, 0].mean():.1f} | "
            + ("—" if label == CURRENT else " / ".join(f"{d:+.1f}" for d in ds))
            + f" | {np.median(allr[:, 2]):.0f} | {ms:.1f} | {ms / base_ms:.2f} |"
        )
    out += [
        "",
        f"Seed noise of the defaults: mean F-score per seed "
        f"{' / '.join(f'{f:.4f}' for f in base_f)} (spread {max(base_f) - min(base_f):.4f}).",
    ]
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sets", default=",".join(SETS), help=f"comma list of {list(SETS)}")
    ap.add_argument("--max-pairs", type=int, default=100, help="data_lines pairs (0: all)")
    ap.add_argument("--step", type=int, default=1, help="every STEP-th pair of data/pairs.json")
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--configs", default="", help="';'-separated labels (default: all)")
    ap.add_argument("--cache", type=Path, default=REPO / ".cache" / "matches")
    ap.add_argument("--write-docs", action="store_true")
    ap.add_argument("--doc", type=Path, default=bench_docs.BENCH_DOC, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    names = [s for s in a.sets.split(",") if s]
    unknown = [s for s in names if s not in SETS]
    if unknown:
        ap.error(f"unknown sets {unknown}; known: {list(SETS)}")
    configs = [c.strip() for c in a.configs.split(";") if c.strip()] or list(ALTERNATIVES)
    bad = [c for c in configs if c not in ALTERNATIVES]
    if bad:
        ap.error(f"unknown configs {bad}; known: {list(ALTERNATIVES)}")
    configs = [CURRENT] + [c for c in configs if not is_default(c)]
    seeds = [int(s) for s in a.seeds.split(",")]
    print(f"warm-up {warm_up_geometry():.1f} s", file=sys.stderr)
    parts = []
    for name in names:
        items, which = load_set(name, a.cache, a.max_pairs, a.step)
        rows = run_set(name, items, configs, seeds)
        parts.append(f"**{name}**: {which}; seeds {seeds}\n\n{table(rows, seeds)}")
        print(parts[-1] + "\n", flush=True)
    title = f"Race pooling and line thresholds of {DEFAULT_METHOD}: alternatives, same run"
    if a.write_docs:
        args = sys.argv[1:] if argv is None else list(argv)
        if "--cache" in args:  # where the cached matches live does not change the figures
            i = args.index("--cache")
            del args[i : i + 2]
        command = bench_docs.command_line("bench_race_lines.py", args)
        head = (
            f"Default method {DEFAULT_METHOD}, threshold 1 px, confidence 0.99. ΔF-score and "
            "Δsuccess: configuration minus the defaults on the same pairs and seed, one "
            "figure per seed. Options are `EstimatorOptions` fields (see the script's docstring)."
        )
        body = "\n\n".join([head, *parts])
        path = bench_docs.write_section(
            "bench_race_lines", bench_docs.section("bench_race_lines", title, command, body), a.doc
        )
        print(f"wrote {path}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
