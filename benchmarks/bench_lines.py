"""Benchmark on line-rich Strecha scenes: ours against OpenCV and PoseLib, hard setting and the
paper's own protocol.

On the pairs of ../shared/data_lines/pairs.json (Strecha multi-view scenes, GT from the cameras),
all methods run in the same process on the same SIFT matches (the same code path as
bench_estimators.py) in three settings:

- hard, SIFT ratio 0.75 and 0.95: threshold 1 px, confidence 0.99 (as bench_estimators.py);
- paper, SIFT ratio 0.75: threshold 3 px, confidence 0.99 (the paper's Strecha protocol).

Positives are always the matches within 1 px of the GT F (metrics.POSITIVE_PX), whatever the
threshold; the threshold is the estimators' and the one each F's inlier mask is cut at. Printed
per setting and method: F-score (mean ± sd), success % (median GT-inlier error < 1 px and >= 20
positives recovered), failure % (the paper's rule), wrong F reported ok % (runs whose F is not a
success although the method reported it: status "ok" for ours, every returned F for OpenCV and
PoseLib, which report no reason), % inliers, mean error, median hypotheses,
median ms per pair, then per-scene mean F-scores and the ratios: the default method's F-score
minus USAC_ACCURATE's and PoseLib's, and each method's median ms over USAC_MAGSAC's.

The default method is whatever ``sepfm_ros.geometry.estimate_fundamental`` defaults to when this
runs. castle-P19 and castle-P30 share byte-identical images: a pair whose two images are
byte-identical to an earlier pair's is dropped (``--keep-duplicates`` keeps it).

    python benchmarks/bench_lines.py [--max-pairs N] [--seeds 0,1,2] [--methods a,b]
        [--settings hard,paper] [--out FILE.md] [--write-docs [--doc FILE] [--eval-doc FILE]]

``--write-docs`` rewrites this script's section of docs/benchmarks.md (see bench_docs.py) and
docs/eval/strecha_paper_protocol.md (the paper's Strecha table, quoted, beside ours).

Figures are measured on this machine in this run; nothing is asserted.
"""

from __future__ import annotations

import argparse
import inspect
import sys
import time
from pathlib import Path

import bench_docs
import numpy as np
from bench_estimators import run_setting
from lines_prefetch import prefetch

from sepfm_ros.evaluation.manifest import PairSpec, load_manifest
from sepfm_ros.evaluation.matches_cache import file_hash
from sepfm_ros.evaluation.methods import poselib_available, resolve_methods, superansac_methods
from sepfm_ros.geometry import estimate_fundamental
from sepfm_ros.geometry.compiled import warm_up as warm_up_geometry

REPO = Path(__file__).resolve().parent.parent
DATA = REPO.parent / "shared" / "data_lines"
EVAL_DOC = REPO / "docs" / "eval" / "strecha_paper_protocol.md"
METHODS = (
    ["sep5", "sep4", "ransac7", "ransac8", "cv-accurate", "cv-magsac", "cv-ransac"]
    + (["poselib"] if poselib_available() else [])
    + superansac_methods()
)
#: label -> (SIFT ratio, threshold px); confidence is 0.99 in all
SETTINGS = {
    "hard": [(0.75, 1.0), (0.95, 1.0)],
    "paper": [(0.75, 3.0)],
}
#: The paper's Table "Results of the Strecha dataset, based on the ground truth camera poses"
#: (label table:accuracy_strecha in ../shared/paper/separable_four_points_F.tex), quoted:
#: (method, % inliers, F-score mean, F-score sd, mean error px). 569 pairs at 3072x2048.
PAPER_STRECHA = [
    ("RANSAC", 71.2, 0.89, 0.05, 0.61),
    ("LMEDS", 71.1, 0.88, 0.08, 0.57),
    ("Hom-Rot-5", 71.5, 0.90, 0.06, 0.60),
    ("Ours-LMEDS-4", 62.4, 0.81, 0.06, 0.72),
    ("Ours-LMEDS-5", 72.1, 0.90, 0.05, 0.59),
    ("Ours-RANSAC-4", 61.7, 0.82, 0.06, 0.71),
    ("Ours-RANSAC-5", 72.2, 0.91, 0.05, 0.58),
]


def default_method() -> str:
    """The method ``estimate_fundamental`` uses when none is named (read at run time)."""
    return str(inspect.signature(estimate_fundamental).parameters["method"].default)


def select_pairs(
    pairs: list[PairSpec], max_pairs: int = 0, keep_duplicates: bool = False
) -> tuple[list[PairSpec], str]:
    """Pairs to run and a sentence saying which: duplicates (same two image files' bytes as an
    earlier pair) dropped unless kept, then ``max_pairs`` evenly spaced ones (0: all)."""
    n_all = len(pairs)
    note = []
    if not keep_duplicates:
        seen, kept = set(), []
        hashes: dict[Path, str] = {}
        for p in pairs:
            key = frozenset(hashes.setdefault(q, file_hash(q)) for q in (p.img_a, p.img_b))
            if key not in seen:
                seen.add(key)
                kept.append(p)
        if len(kept) < n_all:
            note.append(
                f"{n_all - len(kept)} pairs dropped as byte-identical to an earlier pair "
                "(castle-P19 / castle-P30)"
            )
        pairs = kept
    if max_pairs and max_pairs < len(pairs):
        idx = np.unique(np.linspace(0, len(pairs) - 1, max_pairs).round().astype(int))
        note.append(f"{len(idx)} evenly spaced pairs of the {len(pairs)} (--max-pairs)")
        pairs = [pairs[i] for i in idx]
    head = f"{len(pairs)} of the {n_all} pairs of data_lines/pairs.json"
    return pairs, head + (": " + "; ".join(note) if note else "")


def _hyp(rs: list[dict]) -> str:
    v = [r["hyp"] for r in rs if r["hyp"] is not None]
    return f"{np.median(v):.0f}" if v else "n/a"


def _nanmean(values: list[float]) -> float:
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    return float(v.mean()) if len(v) else float("nan")


def summary(rs: list[dict]) -> dict:
    """Aggregates of one method's runs (rows of bench_estimators.run_setting)."""
    f = np.array([r["f"] for r in rs])
    ev = [r for r in rs if r["evaluable"]]
    return {
        "f": f.mean(),
        "sd": f.std(),
        "ok": 100 * np.mean([r["ok"] for r in rs]),
        "wrong_ok": 100 * np.mean([r["wrong_ok"] for r in rs]),
        "fail": 100 * np.mean([r["failed"] for r in ev]) if ev else float("nan"),
        "pct": np.mean([r["pct"] for r in rs]),
        "mean": _nanmean([r["mean"] for r in rs]),
        "hyp": _hyp(rs),
        "ms": float(np.median([r["ms"] for r in rs])),
    }


def method_table(rows: dict, methods: list[str]) -> list[str]:
    out = [
        "| method | F-score (mean ± sd) | success % | failure % | wrong F reported ok % "
        "| % inliers | mean error px | hypotheses (median) | ms per pair (median) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for name in methods:
        s = summary(rows[name])
        out.append(
            f"| {name} | {s['f']:.3f} ± {s['sd']:.3f} | {s['ok']:.1f} | {s['fail']:.1f} | "
            f"{s['wrong_ok']:.1f} | {s['pct']:.1f} | {s['mean']:.3f} | {s['hyp']} | {s['ms']:.1f} |"
        )
    return out


def group_table(rows: dict, methods: list[str], key: str = "scene") -> list[str]:
    """Mean F-score per value of ``key`` ("scene" or "baseline") and method."""
    groups = list(dict.fromkeys(r[key] for r in rows[methods[0]]))
    out = [
        f"| {key} | runs | " + " | ".join(methods) + " |",
        "|---" * (2 + len(methods)) + "|",
    ]
    for g in groups:
        cells = [np.mean([r["f"] for r in rows[m] if r[key] == g]) for m in methods]
        n = sum(r[key] == g for r in rows[methods[0]])
        out.append(f"| {g or '?'} | {n} | " + " | ".join(f"{c:.3f}" for c in cells) + " |")
    return out


def ratio_lines(rows: dict, methods: list[str], default: str) -> list[str]:
    fs = {m: np.mean([r["f"] for r in rows[m]]) for m in methods}
    ms = {m: np.median([r["ms"] for r in rows[m]]) for m in methods}
    out = []
    if default in fs:
        diffs = [
            f"minus {b}'s: {fs[default] - fs[b]:+.3f}" if b in fs else f"minus {b}'s: n/a (not run)"
            for b in ("cv-accurate", "poselib", "superansac", "superansac-adaptive")
        ]
        out.append(f"- default method ({default}) F-score " + "; ".join(diffs))
    else:
        out.append(f"- default method ({default}) not run")
    if "cv-magsac" in ms and ms["cv-magsac"] > 0:
        parts = [f"{m} {ms[m] / ms['cv-magsac']:.2f}" for m in methods if m != "cv-magsac"]
        out.append("- median ms / cv-magsac's (same run): " + ", ".join(parts))
    else:
        out.append("- median ms / cv-magsac's: cv-magsac not run")
    return out


def report(label: str, ratio: float, threshold: float, rows: dict, methods, default) -> str:
    first = rows[methods[0]]
    outl = np.array([r["out"] for r in first])
    out = [
        f"**{label}: SIFT ratio {ratio}, threshold {threshold:g} px, confidence 0.99**",
        "",
        f"{len(first)} runs; outlier rate (matches > 1 px from GT F): median "
        f"{np.median(outl):.2f}, mean {outl.mean():.2f}; matches per pair median "
        f"{np.median([r['n'] for r in first]):.0f}",
        "",
        *method_table(rows, methods),
        "",
        "- wrong F reported ok: runs whose F is not a success although the method reported it "
        '(ours: status "ok"; OpenCV and PoseLib give no status and report every F they return)',
        *ratio_lines(rows, methods, default),
        "",
        "Mean F-score per scene:",
        "",
        *group_table(rows, methods, "scene"),
        "",
        "Mean F-score per baseline (parallax: small < 15 deg <= medium < 30 deg <= wide):",
        "",
        *group_table(rows, methods, "baseline"),
        "",
    ]
    return "\n".join(out)


def paper_doc(title: str, command: str, ours: str, methods: list[str], default: str) -> str:
    """docs/eval/strecha_paper_protocol.md: the paper's Strecha table (quoted) beside ours."""
    paper = [
        "| method (paper) | % inliers | F-score (mean ± sd) | mean error px |",
        "|---|---|---|---|",
        *(f"| {m} | {p:.1f} | {f:.2f} ± {sd:.2f} | {e:.2f} |" for m, p, f, sd, e in PAPER_STRECHA),
    ]
    return "\n".join(
        [
            "# Strecha, the paper's protocol: the paper's table beside ours",
            "",
            "Written by `benchmarks/bench_lines.py --write-docs`; rerun it to regenerate.",
            "",
            "## Quoted from the paper",
            "",
            "Table *Results of the Strecha dataset, based on the ground truth camera poses*",
            "(`table:accuracy_strecha` in `separable_four_points_F.tex`), quoted as printed: 569",
            "pairs of eight Strecha collections at 3072x2048, SIFT ratio 0.75, threshold 3 px,",
            "positives = matches within 1 px of the GT F (symmetric epipolar distance). The",
            "paper's Ours-RANSAC-5 and Ours-RANSAC-4 are the separable estimator with its",
            "5-point (eight-point completion) and 4-point (seven-point completion) stage 2, our",
            "`sep5` and `sep4`; its RANSAC and LMEDS baselines are closest to our `ransac7` /",
            "`cv-ransac` and `cv-lmeds`; Hom-Rot-5 (Barath's five-point solver in GC-RANSAC)",
            "has no counterpart here, USAC_ACCURATE (`cv-accurate`, GC-RANSAC based) is the",
            "nearest.",
            "",
            *paper,
            "",
            f"## Ours: {title}",
            "",
            f"Produced by `{command}` on {bench_docs.machine_description()}.",
            "",
            f"Default method of `estimate_fundamental` at run time: `{default}`. Methods: "
            + ", ".join(f"`{m}`" for m in methods)
            + ".",
            "",
            ours.strip(),
            "",
            "## Differences from the paper's setting",
            "",
            "- Images are the Strecha images downscaled by 0.5 (1536x1024), so 3 px here is 6 px"
            " of the paper's images and the 1 px positive band is 2 px of theirs.",
            "- Six scenes (fountain-P11, Herz-Jesu-P8, entry-P10, castle-P19, castle-P30,"
            " Herz-Jesu-P25), 387 validated pairs (axes within 40 degrees, >= 20 SIFT matches"
            " within 1 px), byte-identical castle pairs dropped; the paper's 569 pairs came"
            " from eight collections.",
            "- % inliers and the mean error are computed from each method's F by one rule for"
            " all methods (metrics.py): inliers are matches within the threshold of the"
            " estimated F, and the mean error is the mean symmetric epipolar distance of the"
            " positives under the estimated F. The paper does not define its *Mean* column"
            " further.",
            "- The paper tuned its baselines by grid search; ours run at the same threshold and"
            " confidence with the libraries' other defaults.",
            "- As in the paper, positives stay the matches within 1 px of the GT F at the 3 px"
            " threshold, so kept matches 1 to 3 px from the GT F count against precision: the"
            " F-scores here are lower than at 1 px on the same matches (docs/benchmarks.md).",
            "",
        ]
    )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--manifest", type=Path, default=DATA / "pairs.json")
    ap.add_argument("--max-pairs", type=int, default=0, help="evenly spaced subset (0: all)")
    ap.add_argument("--keep-duplicates", action="store_true")
    ap.add_argument("--seeds", default="0,1,2", help="comma-separated seeds")
    ap.add_argument("--methods", default=",".join(METHODS), help="comma list (evaluation names)")
    ap.add_argument("--settings", default="hard,paper", help=f"comma list of {list(SETTINGS)}")
    ap.add_argument("--out", type=Path, default=None, help="also write the report here (.md)")
    ap.add_argument("--write-docs", action="store_true")
    ap.add_argument("--doc", type=Path, default=bench_docs.BENCH_DOC, help=argparse.SUPPRESS)
    ap.add_argument("--eval-doc", type=Path, default=EVAL_DOC, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if not a.manifest.is_file():
        print(f"data not found at {a.manifest}", file=sys.stderr)
        return 2
    try:
        methods = [m.name for m in resolve_methods(a.methods)]
        labels = [s.strip() for s in a.settings.split(",") if s.strip()]
        bad = [s for s in labels if s not in SETTINGS]
        if bad or not labels:
            raise ValueError(f"unknown settings {bad}; known: {list(SETTINGS)}")
    except ValueError as e:
        print(e, file=sys.stderr)
        return 2
    default = default_method()
    all_pairs, errors = load_manifest(a.manifest)
    for e in errors:
        print(f"skipped {e.pair_id}: {e.message}", file=sys.stderr)
    pairs, which = select_pairs(all_pairs, a.max_pairs, a.keep_duplicates)
    seeds = [int(s) for s in a.seeds.split(",")]
    runs = [(lab, r, t) for lab in labels for r, t in SETTINGS[lab]]
    t_start = time.time()
    prefetch(pairs, sorted({r for _, r, _ in runs}))
    # compile (or load) the estimator's numba kernels now, so no timed call pays for it
    print(f"warm-up {warm_up_geometry():.1f} s", file=sys.stderr)
    texts, paper_text = [], None
    for lab, ratio, thr in runs:
        rows = run_setting(pairs, ratio, seeds, threshold=thr, methods=methods)
        text = report(lab, ratio, thr, rows, methods, default)
        texts.append(text)
        if lab == "paper":
            paper_text = text
    total = time.time() - t_start
    title = f"Line-rich Strecha benchmark ({len(pairs)} pairs, seeds {seeds})"
    head = [
        f"## {title}",
        "",
        f"{which}. Default method at run time: {default}. Total time {total:.0f} s "
        "(matching included, cached matches reused).",
        "",
    ]
    print("\n".join(head + texts))
    if a.out:
        a.out.parent.mkdir(parents=True, exist_ok=True)
        a.out.write_text("\n".join(head + texts) + "\n")
    if a.write_docs:
        args = sys.argv[1:] if argv is None else list(argv)
        if "--out" in args:  # where a copy went does not change the figures
            i = args.index("--out")
            del args[i : i + 2]
        command = bench_docs.command_line("bench_lines.py", args)
        body = "\n".join(head[2:] + texts)
        path = bench_docs.write_section(
            "bench_lines", bench_docs.section("bench_lines", title, command, body), a.doc
        )
        print(f"wrote {path}", file=sys.stderr)
        if paper_text is not None:
            ours = f"{which}.\n\n{paper_text}"
            a.eval_doc.parent.mkdir(parents=True, exist_ok=True)
            a.eval_doc.write_text(paper_doc(title, command, ours, methods, default))
            print(f"wrote {a.eval_doc}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
