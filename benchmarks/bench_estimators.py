"""Benchmark: the separable estimator against OpenCV, PoseLib, SupeRANSAC and our own baselines.

On the pairs of ../shared/data/pairs.json with SIFT matches at ratio 0.75 and at a hard 0.95, all
methods run in the same process on the same matches at equal threshold (1 px) and confidence
(0.99). Printed per setting: F-score of the inlier mask against GT inliers (matches within 1 px of
the GT F), median GT-inlier error, success rate (median GT-inlier error < 1 px and >= 20 GT
inliers recovered), hypotheses, and median ms per pair; then the ratios the targets are stated in.
Each method's timed runs on a pair follow an untimed run of it on the same matches
(``compiled_work.warm_up``), so none is timed right after another library's runs.

    python benchmarks/bench_estimators.py [--step 1] [--seeds 0,1,2] [--ratios 0.75,0.95]
        [--out FILE.md] [--write-docs [--readme README.md]]

``--write-docs`` rewrites this script's section of docs/benchmarks.md (see bench_docs.py),
including the headline table that README shows.

Figures are measured on this machine in this run; nothing is asserted.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import bench_docs
import numpy as np
from compiled_work import warm_up

from sepfm_ros.evaluation.manifest import load_manifest
from sepfm_ros.evaluation.matches_cache import MatchesCache, MatchSettings
from sepfm_ros.evaluation.methods import REGISTRY, poselib_available, superansac_methods
from sepfm_ros.evaluation.metrics import positives, run_metrics
from sepfm_ros.geometry import DEFAULT_METHOD

REPO = Path(__file__).resolve().parent.parent
DATA = REPO.parent / "shared" / "data"
METHODS = ["sep4", "sep5", "ransac7", "ransac8", "cv-ransac", "cv-lmeds", "cv-magsac",
           "cv-accurate"] + (["poselib"] if poselib_available() else [])  # fmt: skip
METHODS += superansac_methods()


def run_setting(
    pairs, ratio: float, seeds: list[int], threshold: float = 1.0, methods: list[str] | None = None
) -> dict:
    """Every method x seed on every pair's SIFT matches at ``ratio``: {method: [row per run]}.

    Positives are the matches within 1 px of the GT F whatever ``threshold`` is (metrics.py);
    ``threshold`` is the estimators' inlier threshold and the one the inlier mask is cut at.
    """
    methods = METHODS if methods is None else methods
    cache = MatchesCache(REPO / ".cache" / "matches", MatchSettings("sift", ratio))
    rows = {m: [] for m in methods}
    t0 = time.time()
    for i, pair in enumerate(pairs):
        m = cache.matches(pair)
        pos = positives(pair.F_gt, m.pts_a, m.pts_b)
        outlier_rate = 1.0 - pos.mean()
        for name in methods:
            warm_up(REGISTRY[name].run, m.pts_a, m.pts_b, m.size_a, m.size_b, threshold, 0.99, 0)
            for seed in seeds:
                r = REGISTRY[name].run(m.pts_a, m.pts_b, m.size_a, m.size_b, threshold, 0.99, seed)
                met = run_metrics(r.F, m.pts_a, m.pts_b, pos, threshold)
                med = met.median_error if r.F is not None else np.inf
                ok = met.succeeded
                rows[name].append({
                    "pair": pair.pair_id, "scene": pair.scene, "baseline": pair.baseline,
                    "f": met.f_score, "med": med, "mean": met.mean_error, "pct": met.pct_inliers,
                    "failed": met.failed,
                    "evaluable": met.evaluable, "ok": ok, "hyp": r.hypotheses, "ms": r.ms,
                    "wrong_ok": r.F is not None and r.status == "ok" and not ok,
                    "line": r.line_pair is not None, "out": outlier_rate, "n": len(pos),
                })  # fmt: skip
        el = time.time() - t0
        sys.stderr.write(
            f"\r  ratio {ratio}, threshold {threshold} px: {i + 1}/{len(pairs)} pairs, {el:.0f} s"
        )
    sys.stderr.write("\n")
    return rows


def _fmt_hyp(vals: list) -> str:
    v = [x for x in vals if x is not None]
    return f"{np.median(v):.0f} / {np.mean(v):.0f}" if v else "n/a"


def report(ratio: float, rows: dict) -> str:
    out = [f"**SIFT ratio {ratio}**", ""]
    n = len(rows["sep5"])
    outl = np.array([r["out"] for r in rows["sep5"]])
    out.append(f"{n} runs; outlier rate (matches > 1 px from GT F): median {np.median(outl):.2f},"
               f" mean {outl.mean():.2f}; matches per pair median "
               f"{np.median([r['n'] for r in rows['sep5']]):.0f}")  # fmt: skip
    out += ["", "| method | F-score (mean ± sd) | median GT-inlier err px (median) | success % "
            "| hypotheses (median / mean) | ms per pair (median) |",
            "|---|---|---|---|---|---|"]  # fmt: skip
    for name in METHODS:
        rs = rows[name]
        f = np.array([r["f"] for r in rs])
        med = np.array([r["med"] for r in rs])
        out.append(
            f"| {name} | {f.mean():.3f} ± {f.std():.3f} | {np.median(med):.3f} | "
            f"{100 * np.mean([r['ok'] for r in rs]):.1f} | {_fmt_hyp([r['hyp'] for r in rs])} | "
            f"{np.median([r['ms'] for r in rs]):.1f} |"
        )
    s4, r7 = rows["sep4"], rows["ransac7"]
    used = [i for i, r in enumerate(s4) if r["line"]]
    ratios = np.array([s4[i]["hyp"] / max(1, r7[i]["hyp"]) for i in used])
    hard = [i for i in used if s4[i]["out"] >= 0.5]
    hard_ratio = [s4[i]["hyp"] / max(1, r7[i]["hyp"]) for i in hard]
    ms = {k: np.median([r["ms"] for r in rows[k]]) for k in METHODS}
    fs = {k: np.mean([r["f"] for r in rows[k]]) for k in METHODS}
    d = DEFAULT_METHOD
    out += [
        "",
        f"- sep4 / ransac7 hypotheses, median over the {len(used)} runs that used a line pair: "
        f"{np.median(ratios):.2f} (ratio of medians "
        f"{np.median([s4[i]['hyp'] for i in used]) / np.median([r7[i]['hyp'] for i in used]):.2f},"
        f" ratio of means {np.sum([s4[i]['hyp'] for i in used]) / np.sum([r7[i]['hyp'] for i in used]):.2f});"  # noqa: E501
        f" on the {len(hard)} runs with outlier rate >= 0.5: "
        f"{np.median(hard_ratio) if hard else float('nan'):.2f}",
        f"- {d} (default) F-score minus USAC_MAGSAC's: {fs[d] - fs['cv-magsac']:+.3f}; minus "
        f"USAC_ACCURATE's: {fs[d] - fs['cv-accurate']:+.3f}; minus FM_RANSAC's: "
        f"{fs[d] - fs['cv-ransac']:+.3f}",
        f"- {d} median ms / USAC_MAGSAC's: {ms[d] / ms['cv-magsac']:.2f}; / FM_RANSAC's: "
        f"{ms[d] / ms['cv-ransac']:.2f}",
        "",
    ]
    return "\n".join(out)


def headline(settings: dict[float, dict]) -> str:
    """README's headline table: F-score and median ms per pair of our methods, OpenCV's and
    PoseLib's, one column pair per SIFT ratio setting."""
    names = [m for m in ("sep4", "sep5", "ransac7", "cv-ransac", "cv-magsac", "cv-accurate",
                         "poselib", "superansac", "superansac-adaptive")
             if m in METHODS]  # fmt: skip
    head = "| method | " + " | ".join(
        f"F-score (SIFT {r}) | ms per pair (SIFT {r})" for r in settings
    )
    out = [head + " |", "|---" * (1 + 2 * len(settings)) + "|"]
    for name in names:
        cells = []
        for rows in settings.values():
            rs = rows[name]
            f_score, ms = np.mean([r["f"] for r in rs]), np.median([r["ms"] for r in rs])
            cells += [f"{f_score:.3f}", f"{ms:.1f}"]
        out.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--step", type=int, default=1, help="use every STEP-th pair")
    ap.add_argument("--seeds", default="0,1,2", help="comma-separated seeds")
    ap.add_argument("--ratios", default="0.75,0.95")
    ap.add_argument("--out", type=Path, default=None, help="also write the report here (.md)")
    ap.add_argument(
        "--write-docs", action="store_true", help="rewrite this section of docs/benchmarks.md"
    )
    ap.add_argument(
        "--readme",
        type=Path,
        default=None,
        help="with --write-docs: also copy the headline table into this README's "
        "<!-- headline:begin/end --> markers",
    )
    a = ap.parse_args(argv)
    if not (DATA / "pairs.json").is_file():
        print(f"shared data not found at {DATA}", file=sys.stderr)
        return 2
    pairs, errors = load_manifest(DATA / "pairs.json")
    pairs = pairs[:: a.step]
    seeds = [int(s) for s in a.seeds.split(",")]
    title = (
        f"Estimator benchmark ({len(pairs)} pairs, seeds {seeds}, threshold 1 px, confidence 0.99)"
    )
    settings = {float(r): run_setting(pairs, float(r), seeds) for r in a.ratios.split(",")}
    text = [report(ratio, rows) for ratio, rows in settings.items()]
    print("\n".join([f"## {title}", "", *text]))
    if a.out:
        a.out.parent.mkdir(parents=True, exist_ok=True)
        a.out.write_text("\n".join([f"## {title}", "", *text]) + "\n")
    if a.write_docs:
        begin, end = bench_docs.markers(bench_docs.HEADLINE)
        body = "\n".join(["Headline (README):", "", begin, headline(settings), end, "", *text])
        command = bench_docs.command_line("bench_estimators.py", argv)
        path = bench_docs.write_section(
            "bench_estimators", bench_docs.section("bench_estimators", title, command, body)
        )
        print(f"wrote {path}", file=sys.stderr)
        if a.readme:
            problem = bench_docs.update_headline(a.readme, path)
            if problem:
                print(f"headline not updated: {problem}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
