"""The evaluation report: ``report.md``, ``runs.csv``, ``pairs.csv``, ``summary.json`` and PNGs.

Figures (matplotlib, Agg backend, no display needed):

- ``fig4_trials.png``: the paper's Fig. 4, theoretical RANSAC trials F(k, r) against the outlier
  rate for 7-point, 5-point, ours with 7-point (F(3,r)+F(4,r)) and ours with 8-point
  (F(3,r)+F(5,r)), next to the measured hypotheses per run against the pair's GT outlier rate
  (median per outlier-rate bin), for the methods that expose a count.
- ``fig7_line_inliers.png``: inliers per matched line pair (histogram, the paper's Fig. 7).
- ``fig8_line_homography_cdf.png``: CDF per scene of the line homography error (Fig. 8) of the
  line inliers, under the estimator's stage-1 H_e (solid) and the H_e the GT F induces (dashed).
- ``error_cdf.png``: CDF of the per-run mean symmetric epipolar error of the positives, per method.
- ``example_<scene>.png``: one pair per scene with the line pair, inliers and epipolar lines.
"""

from __future__ import annotations

import csv
import json
import math
import re
from dataclasses import asdict
from pathlib import Path

import cv2
import numpy as np

from sepfm_ros.evaluation import metrics
from sepfm_ros.evaluation.matches_cache import read_image
from sepfm_ros.evaluation.methods import REGISTRY
from sepfm_ros.evaluation.run import EvalResults, Example, per_pair_values
from sepfm_ros.geometry import ransac_trials

OVERALL = "overall"
README_START = "<!-- eval-table:start -->"
README_END = "<!-- eval-table:end -->"


def _fmt(x: float | None, digits: int = 2) -> str:
    if x is None:
        return "n/a"
    if isinstance(x, float) and math.isnan(x):
        return "–"
    return f"{x:.{digits}f}"


def summaries(res: EvalResults) -> dict[str, list[metrics.Summary]]:
    """scene (and ``overall``) -> one Summary per method, in method order."""
    scenes = sorted({r["scene"] for r in res.runs})
    out: dict[str, list[metrics.Summary]] = {}
    for scene in [*scenes, OVERALL]:
        rows = [r for r in res.runs if scene == OVERALL or r["scene"] == scene]
        out[scene] = [
            metrics.summarize(m, [r for r in rows if r["method"] == m]) for m in res.methods
        ]
    return out


def accuracy_table(rows: list[metrics.Summary]) -> str:
    """Markdown table in the layout of the paper's Tables 2-4, plus our extra columns."""
    head = (
        "| method | % inliers | F-score | mean err (px) | median err (px) | failure % "
        "| hypotheses (stage 1 / stage 2) | ms / pair | runs |\n"
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|\n"
    )
    lines = []
    for s in rows:
        if s.hypotheses is None:
            hyp = "n/a"
        elif s.stage1_hypotheses is None:
            hyp = f"{s.hypotheses:.0f}"
        else:
            hyp = f"{s.hypotheses:.0f} ({s.stage1_hypotheses:.0f} / {s.stage2_hypotheses:.0f})"
        lines.append(
            f"| {s.method} | {_fmt(s.pct_inliers, 1)} | {_fmt(s.f_score_mean)} ± "
            f"{_fmt(s.f_score_std)} | {_fmt(s.mean_error)} | {_fmt(s.median_error)} | "
            f"{_fmt(s.failure_pct, 1)} | {hyp} | {_fmt(s.ms_mean, 1)} | {s.runs} |"
        )
    return head + "\n".join(lines) + "\n"


def pose_table(res: EvalResults) -> str:
    """Markdown table of relative-pose errors per method (pairs with GT cameras), or ""."""
    lines = []
    for method in res.methods:
        n, rot, tdir = metrics.pose_summary([r for r in res.runs if r["method"] == method])
        if n:
            lines.append(f"| {method} | {_fmt(rot, 3)} | {_fmt(tdir, 2)} | {n} |")
    if not lines:
        return ""
    head = (
        "| method | median rotation err (deg) | median translation-direction err (deg) "
        "| pairs |\n|---|---:|---:|---:|\n"
    )
    return head + "\n".join(lines) + "\n"


def failure_table(res: EvalResults, rows: list[metrics.Summary]) -> str:
    """The paper's Table 5 for our data: hypotheses and failures, overall and relative to the
    baseline (runs that fail where the baseline, same pair and seed, does not)."""
    base = res.config.baseline
    base_fail = {(r["pair"], r["seed"]): r["failed"] for r in res.runs if r["method"] == base}
    head = (
        f"| method | hypotheses | failure % | failures where {base} succeeds (%) |\n"
        "|---|---:|---:|---:|\n"
    )
    lines = []
    for s in rows:
        runs = [r for r in res.runs if r["method"] == s.method and r["evaluable"]]
        paired = [r for r in runs if (r["pair"], r["seed"]) in base_fail]
        extra = [r for r in paired if r["failed"] and not base_fail[(r["pair"], r["seed"])]]
        rel = 100.0 * len(extra) / len(paired) if paired and base_fail else math.nan
        hyp = "n/a" if s.hypotheses is None else f"{s.hypotheses:.0f}"
        lines.append(f"| {s.method} | {hyp} | {_fmt(s.failure_pct, 1)} | {_fmt(rel, 1)} |")
    return head + "\n".join(lines) + "\n"


def comparisons(res: EvalResults) -> list[metrics.PairedComparison]:
    """Every method against the baseline on F-score (higher better) and mean error (lower)."""
    base = res.config.baseline
    if base not in res.methods:
        return []
    out = []
    for metric, higher in (("f_score", True), ("mean_error", False)):
        b = per_pair_values(res.runs, base, metric)
        for m in res.methods:
            if m == base:
                continue
            v = per_pair_values(res.runs, m, metric)
            out.append(metrics.paired_comparison(m, base, metric, v, b, higher_is_better=higher))
    return out


def comparison_table(comps: list[metrics.PairedComparison]) -> str:
    head = (
        "| method | metric | pairs | wins / losses / ties | win fraction [95% CI] | sign-test p "
        "| mean diff [95% CI] |\n|---|---|---:|---:|---:|---:|---:|\n"
    )
    lines = [
        f"| {c.method} | {c.metric} ({'higher' if c.higher_is_better else 'lower'} is better) | "
        f"{c.pairs} | {c.wins} / {c.losses} / {c.ties} | {_fmt(c.win_fraction)} "
        f"[{_fmt(c.win_ci[0])}, {_fmt(c.win_ci[1])}] | {c.p_value:.3g} | "
        f"{_fmt(c.mean_diff, 3)} [{_fmt(c.diff_ci[0], 3)}, {_fmt(c.diff_ci[1], 3)}] |"
        for c in comps
    ]
    return head + "\n".join(lines) + "\n"


# ----------------------------------------------------------------------------------- figures


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def fig4_trials(res: EvalResults, path: Path) -> None:
    """Theoretical trial counts (left) and measured hypotheses per pair (right)."""
    plt = _plt()
    p = res.config.confidence
    r = np.linspace(0.0, 0.9, 91)
    curves = {
        "7pts: F(7,r)": [ransac_trials(7, x, p) for x in r],
        "5pts: F(5,r)": [ransac_trials(5, x, p) for x in r],
        "Ours-7pts: F(3,r)+F(4,r)": [ransac_trials(3, x, p) + ransac_trials(4, x, p) for x in r],
        "Ours-8pts: F(3,r)+F(5,r)": [ransac_trials(3, x, p) + ransac_trials(5, x, p) for x in r],
    }
    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(11, 4.2))
    for k, (label, ys) in enumerate(curves.items()):
        ax0.semilogy(r, ys, label=label)
        ax1.semilogy(r, ys, color="0.7", lw=0.8, label="theory (left)" if k == 0 else None)
    ax0.set(xlabel="outlier rate r", ylabel="RANSAC trials", title=f"Theoretical (p = {p})")
    ax0.grid(True, which="both", alpha=0.3)
    ax0.legend(fontsize=8)
    orate = {q["pair"]: q["outlier_rate"] for q in res.pairs}
    plotted = False
    for name in res.methods:
        runs = [x for x in res.runs if x["method"] == name and x["hypotheses"] is not None]
        if not runs:
            continue
        xs = np.array([orate[x["pair"]] for x in runs])
        ys = np.array([max(1, x["hypotheses"]) for x in runs], dtype=np.float64)
        # median per outlier-rate bin of width 0.1 (bins with runs only), runs as faint dots
        bins = np.floor(xs / 0.1).astype(int)
        centres, medians = [], []
        for b in np.unique(bins):
            centres.append(float(np.mean(xs[bins == b])))
            medians.append(float(np.median(ys[bins == b])))
        line = ax1.plot(centres, medians, marker="o", ms=4, lw=1.5, label=name)[0]
        ax1.scatter(xs, ys, s=3, alpha=0.15, color=line.get_color())
        plotted = True
    ax1.set_yscale("log")
    ax1.set(
        xlabel="GT outlier rate of the pair (1 - positives / matches)",
        ylabel="hypotheses scored",
        title="Measured (median per 0.1 bin; dots: runs)",
        xlim=(0, 0.9),
    )
    ax1.grid(True, which="both", alpha=0.3)
    if plotted:
        ax1.legend(fontsize=7, ncol=2)
    else:
        ax1.text(
            0.5, 0.5, "no method exposes hypothesis counts", ha="center", transform=ax1.transAxes
        )
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def fig7_line_inliers(res: EvalResults, path: Path) -> None:
    plt = _plt()
    fig, ax = plt.subplots(figsize=(5.5, 3.8))
    counts = [c for _, c in res.line_inliers]
    if counts:
        bins = np.arange(0, max(counts) + 2) - 0.5
        ax.hist(counts, bins=bins, density=True, color="tab:blue", alpha=0.8)
        ax.set_title(
            f"Inliers per matched line pair (mean {np.mean(counts):.2f}, {len(counts)} runs)",
            fontsize=10,
        )
    else:
        ax.text(0.5, 0.5, "no separable run found a line pair", ha="center", transform=ax.transAxes)
    ax.set(xlabel="line inliers", ylabel="probability")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _cdf(ax, values, label, **style):
    v = np.sort(np.asarray(values, dtype=np.float64))
    if v.size == 0:
        return
    y = np.arange(1, v.size + 1) / v.size
    ax.step(v, y, where="post", label=label, **style)


def fig8_line_homography_cdf(res: EvalResults, path: Path) -> None:
    """CDF per scene of the line homography error of the line inliers under the estimator's
    stage-1 H_e (solid) and the H_e induced by the GT F (dashed)."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.5, 4.2))
    scenes = sorted(set(res.line_errors_est) | set(res.line_errors_gt))
    for k, scene in enumerate(scenes):
        color = f"C{k % 10}"
        for vals, style, what in (
            (res.line_errors_est.get(scene, []), "-", "stage-1 H_e"),
            (res.line_errors_gt.get(scene, []), "--", "GT F"),
        ):
            if vals:
                share = 100.0 * np.mean(np.asarray(vals) <= 0.5)
                label = f"{scene}, {what} ({share:.0f}% <= 0.5 px)"
                _cdf(ax, vals, label, color=color, linestyle=style)
    if scenes:
        ax.legend(fontsize=7, loc="lower right")
    else:
        ax.text(0.5, 0.5, "no separable run found a line pair", ha="center", transform=ax.transAxes)
    ax.set_xlim(0, 3)
    ax.set(
        xlabel="line homography error (px, along the lines)",
        ylabel="CDF",
        title="Line homography error of the line inliers",
    )
    ax.grid(True, alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def error_cdf(res: EvalResults, path: Path) -> None:
    """CDF of the per-run mean symmetric epipolar error of positives; no F counts as infinite."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.5, 4.2))
    for name in res.methods:
        vals = [
            math.inf if math.isnan(x["mean_error"]) else x["mean_error"]
            for x in res.runs
            if x["method"] == name and x["n_positives"] > 0
        ]
        _cdf(ax, vals, name)
    ax.set_xscale("log")
    ax.set_xlim(0.05, 100)
    ax.set_ylim(0, 1.01)
    ax.set(
        xlabel="mean symmetric epipolar distance of the GT positives (px)",
        ylabel="fraction of runs",
        title="Error CDF per method (no model = never reached)",
    )
    ax.grid(True, which="both", alpha=0.3)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=7, ncol=2, loc="upper left")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _line_segment(line, w, h):
    """End points of line (a, b, c) clipped to the w x h image, or None."""
    a, b, c = (float(v) for v in line)
    pts = []
    if abs(b) > 1e-12:
        for u in (0.0, w - 1.0):
            v = -(a * u + c) / b
            if 0 <= v <= h - 1:
                pts.append((u, v))
    if abs(a) > 1e-12:
        for v in (0.0, h - 1.0):
            u = -(b * v + c) / a
            if 0 <= u <= w - 1:
                pts.append((u, v))
    if len(pts) < 2:
        return None
    return tuple(int(round(x)) for x in pts[0]), tuple(int(round(x)) for x in pts[-1])


def _canvas(ex: Example, which: str) -> np.ndarray:
    path = ex.pair.img_a if which == "a" else ex.pair.img_b
    size = ex.pair.size_a if which == "a" else (ex.pair.size_b or ex.pair.size_a)
    if path is not None:
        img = read_image(path)
        if img.dtype != np.uint8:
            img = cv2.normalize(img, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
        if img.ndim == 3:  # grey background: the coloured overlays stand out, PNGs stay small
            img = cv2.cvtColor(img[..., :3], cv2.COLOR_BGR2GRAY)
        return cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    w, h = size
    return np.full((h, w, 3), 40, dtype=np.uint8)


def example_figure(
    ex: Example, threshold: float, path: Path, n_lines: int = 12, max_width: int = 900
) -> None:
    """Both images side by side: putative matches (grey), inliers of the run (green), the line
    pair (blue), its inliers (red circles), and epipolar lines of a few inliers (yellow)."""
    canv = [_canvas(ex, "a"), _canvas(ex, "b")]
    r = ex.result
    inl = metrics.inlier_mask(r.F, ex.pts_a, ex.pts_b, threshold)
    for k, pts in enumerate((ex.pts_a, ex.pts_b)):
        img = canv[k]
        h, w = img.shape[:2]
        t = max(1, w // 640)
        if r.F is not None:
            idx = np.flatnonzero(inl)
            pick = (
                idx[np.linspace(0, len(idx) - 1, min(n_lines, len(idx))).astype(int)]
                if len(idx)
                else idx
            )
            other = ex.pts_a if k == 1 else ex.pts_b
            F = r.F if k == 1 else r.F.T
            for i in pick:
                line = F @ np.array([other[i, 0], other[i, 1], 1.0])
                seg = _line_segment(line, w, h)
                if seg:
                    cv2.line(img, seg[0], seg[1], (0, 220, 255), t, cv2.LINE_AA)
        for i, (u, v) in enumerate(pts):
            color = (0, 200, 0) if inl[i] else (150, 150, 150)
            cv2.circle(img, (int(round(u)), int(round(v))), 2 * t, color, -1, cv2.LINE_AA)
        if r.line_pair is not None:
            seg = _line_segment(r.line_pair[k], w, h)
            if seg:
                cv2.line(img, seg[0], seg[1], (255, 80, 0), 2 * t, cv2.LINE_AA)
            for i in r.line_inliers:
                u, v = pts[int(i)]
                cv2.circle(img, (int(round(u)), int(round(v))), 5 * t, (0, 0, 255), t, cv2.LINE_AA)
    h = max(c.shape[0] for c in canv)
    canv = [cv2.copyMakeBorder(c, 0, h - c.shape[0], 0, 8, cv2.BORDER_CONSTANT) for c in canv]
    out = np.concatenate(canv, axis=1)
    if out.shape[1] > max_width:
        s = max_width / out.shape[1]
        out = cv2.resize(out, None, fx=s, fy=s, interpolation=cv2.INTER_AREA)
    label = (
        f"{ex.pair.pair_id}  {ex.method}: {int(inl.sum())}/{len(inl)} inliers, "
        f"{int(ex.positive.sum())} GT positives, {r.status}"
    )
    band = np.full((26, out.shape[1], 3), 255, dtype=np.uint8)
    cv2.putText(band, label, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.imwrite(str(path), np.concatenate([band, out], axis=0), [cv2.IMWRITE_PNG_COMPRESSION, 9])


# ------------------------------------------------------------------------------------ report


def _safe_name(s: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", s)


def write_csv(path: Path, rows: list[dict]) -> None:
    if not rows:
        path.write_text("")
        return
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0].keys()))
        w.writeheader()
        w.writerows(rows)


def _write_data(
    res: EvalResults,
    out: Path,
    sums: dict[str, list[metrics.Summary]],
    comps: list[metrics.PairedComparison],
) -> None:
    """``runs.csv``, ``pairs.csv`` and ``summary.json`` in ``out``."""
    write_csv(out / "runs.csv", res.runs)
    write_csv(out / "pairs.csv", res.pairs)
    (out / "summary.json").write_text(
        json.dumps(
            {
                "config": asdict(res.config),
                "methods": res.methods,
                "summaries": {k: [asdict(s) for s in v] for k, v in sums.items()},
                "comparisons": [asdict(c) for c in comps],
                "errors": [asdict(e) for e in res.errors],
            },
            indent=1,
            default=str,
        )
    )


def _write_figures(res: EvalResults, out: Path) -> dict[str, str]:
    """The PNGs in ``out``; scene -> its example's file name, or why it could not be drawn."""
    figs = {
        "fig4_trials.png": fig4_trials,
        "fig7_line_inliers.png": fig7_line_inliers,
        "fig8_line_homography_cdf.png": fig8_line_homography_cdf,
        "error_cdf.png": error_cdf,
    }
    for name, fn in figs.items():
        fn(res, out / name)
    example_files = {}
    for scene, ex in sorted(res.examples.items()):
        name = f"example_{_safe_name(scene)}.png"
        try:
            example_figure(ex, res.config.threshold, out / name)
            example_files[scene] = name
        except Exception as exc:  # a drawing problem must not lose the report
            example_files[scene] = f"(could not draw: {exc!r})"
    return example_files


def _intro_md(res: EvalResults, command: str, notes: str) -> list[str]:
    """The report's title, what was evaluated and how (lines of Markdown)."""
    cfg = res.config
    n_seeds = len(cfg.seeds)
    md = ["# Fundamental-matrix estimators on pairs with ground truth", ""]
    if command:
        md += [f"Generated by `{command}`.", ""]
    md += [
        f"{len(res.pairs)} pairs evaluated, {len(res.errors)} pairs could not be evaluated; "
        f"{len(res.methods)} methods x {n_seeds} seeds ({', '.join(map(str, cfg.seeds))}); "
        f"inlier threshold {cfg.threshold} px (symmetric epipolar distance), confidence "
        f"{cfg.confidence}; paired comparisons against `{cfg.baseline}`.",
        "",
        "Metrics are defined in `sepfm_ros/evaluation/metrics.py`: positives are matches within "
        f"{metrics.POSITIVE_PX} px of the GT F; F-score of each method's inlier mask against them "
        "(mean ± std over runs); errors are the symmetric epipolar distances of the positives "
        "under the estimate; a run fails when fewer than "
        f"{metrics.MIN_RECOVERED_POSITIVES} positives are recovered. Hypotheses are shown as "
        "total (stage 1 / stage 2) where a method exposes them, n/a for OpenCV.",
        "",
    ]
    if notes:
        md += [notes, ""]
    return md


def _tables_md(
    res: EvalResults, sums: dict[str, list[metrics.Summary]], comps: list[metrics.PairedComparison]
) -> list[str]:
    """The methods, then the tables: overall, relative pose, failures, paired comparison and one
    accuracy table per scene (lines of Markdown)."""
    methods_desc = [f"- `{m}`: {REGISTRY[m].description}" for m in res.methods if m in REGISTRY]
    md = ["## Methods", "", *methods_desc, ""]
    md += ["## Overall (paper's Tables 2-4 layout)", "", accuracy_table(sums[OVERALL])]
    poses = pose_table(res)
    if poses:
        md += [
            "## Relative pose (pairs with GT cameras)",
            "",
            "Each run's F, its inliers and the GT intrinsics give a pose "
            "(`sepfm_ros.geometry.pose.relative_pose`); errors against the GT cameras' relative "
            f"pose, median over runs; a run without F or pose counts as "
            f"{metrics.POSE_FAILURE_DEG:.0f} deg.",
            "",
            poses,
        ]
    md += ["## Hypotheses and failures (paper's Table 5 layout)", ""]
    md += [failure_table(res, sums[OVERALL])]
    if comps:
        md += [
            f"## Paired comparison against `{res.config.baseline}`",
            "",
            "Per pair, each metric is averaged over seeds; a method wins a pair when it is better. "
            "A win-fraction interval that contains 0.5 means the difference is not distinguishable "
            "from noise on these pairs.",
            "",
            comparison_table(comps),
        ]
    for scene, rows in sums.items():
        if scene == OVERALL:
            continue
        n_pairs = len({p["pair"] for p in res.pairs if p["scene"] == scene})
        md += [f"## Scene `{scene}` ({n_pairs} pairs)", "", accuracy_table(rows)]
    return md


def _figures_md(example_files: dict[str, str]) -> list[str]:
    """The figures section: the four plots, then each scene's example or why it is missing."""
    md = [
        "## Figures",
        "",
        "Theoretical RANSAC trials (paper's Fig. 4) and measured hypotheses per run:",
        "",
        "![trials](fig4_trials.png)",
        "",
        "Inliers per matched line pair (paper's Fig. 7) and line homography error CDF (Fig. 8):",
        "",
        "![line inliers](fig7_line_inliers.png) ![line homography](fig8_line_homography_cdf.png)",
        "",
        "The line homography error is that of the H_e the estimated (solid) or GT (dashed) F "
        "induces on the line pair, after projecting the matches onto the lines. It is large "
        "where the line pair is close to an epipolar line (near-horizontal lines in rectified "
        "stereo, lines towards the epipole under forward motion): there it measures how well "
        "the line pair conditions H_e more than how good F is.",
        "",
        "Symmetric epipolar error of the positives per method:",
        "",
        "![error cdf](error_cdf.png)",
        "",
    ]
    for scene, name in example_files.items():
        if name.endswith(".png"):
            md += [f"Example `{scene}`:", "", f"![{scene}]({name})", ""]
        else:
            md += [f"Example `{scene}`: {name}", ""]
    return md


def _errors_md(res: EvalResults) -> list[str]:
    """The pairs that could not be evaluated and where the data files are (lines of Markdown)."""
    md = ["## Pairs that could not be evaluated", ""]
    if res.errors:
        md += ["| pair | scene | reason |", "|---|---|---|"]
        md += [f"| {e.pair_id} | {e.scene} | {e.message.replace('|', '/')} |" for e in res.errors]
    else:
        md += ["None."]
    md += [
        "",
        "Per-run results: `runs.csv`; per-pair data: `pairs.csv`; all tables: `summary.json`.",
        "",
    ]
    return md


def write_report(res: EvalResults, out: Path, command: str = "", notes: str = "") -> Path:
    """Write the report folder; returns the path of ``report.md``."""
    out.mkdir(parents=True, exist_ok=True)
    sums = summaries(res)
    comps = comparisons(res)
    _write_data(res, out, sums, comps)
    example_files = _write_figures(res, out)
    md = _intro_md(res, command, notes)
    md += _tables_md(res, sums, comps)
    md += _figures_md(example_files)
    md += _errors_md(res)
    path = out / "report.md"
    path.write_text("\n".join(md))
    return path


def update_readme(readme: Path, res: EvalResults, command: str) -> None:
    """Replace the text between the eval-table markers of ``readme`` with the overall table."""
    text = readme.read_text()
    if README_START not in text or README_END not in text:
        raise ValueError(f"{readme} has no {README_START} ... {README_END} markers")
    cfg = res.config
    body = (
        f"{len(res.pairs)} pairs, {len(res.methods)} methods x {len(cfg.seeds)} seeds, threshold "
        f"{cfg.threshold} px, confidence {cfg.confidence} (generated by `{command}`):\n\n"
        + accuracy_table(summaries(res)[OVERALL])
    )
    start = text.index(README_START) + len(README_START)
    end = text.index(README_END)
    readme.write_text(text[:start] + "\n" + body + text[end:])
