"""Benchmark: accuracy of the node's pipeline on native high-resolution frames, with features
found at full size and on the downscaled copy (``feature_max_width``).

The pairs of ../shared/data_lines/pairs.json (Strecha scenes, 1536x1024 photographs, not
upscaled; GT F and cameras from laser-registered poses; pairs whose two images are byte-identical
to an earlier pair's dropped, as bench_lines.py does) are read as the node gets a colour camera's
frames (BGR decoded, one ``cv2.cvtColor`` to grey) and run through ``Pipeline`` at the node's
default ``PipelineConfig`` (ORB 1000, ratio 0.8, sep4, threshold 1 px, confidence 0.99) under two
settings: ``feature_max_width`` 0 (features at 1536x1024, as at the default 1600) and 1280
(1536 > 1280: detected at 768x512, matches mapped back to 1536x1024 pixels), the factor 2 a
1920x1080 camera gets at the default. Every image is detected once per setting.

Printed per setting, over pairs x seeds: matches per pair and GT positives (matches within 1 px of
the GT F) per pair (medians), F-score against those positives (mean ± sd), success % (median
GT-positive error < 1 px and >= 20 positives recovered), the median of the median GT-positive
error (px, full-size pixels), the rotation and translation-direction errors of the pose taken from
each F with the GT intrinsics (``metrics.pose_errors``; no F counts as 180 deg), and the pipeline's
features ms per detected image and estimate ms per pair; then success % and median rotation
error by baseline. The F-score and GT-positive error are each setting's own matches; the pose
errors compare both settings against the same GT.

    python benchmarks/bench_downscale.py [--max-pairs N] [--seeds 0,1,2] [--data DIR]
        [--write-docs [--doc FILE]]

``--write-docs`` rewrites this script's section of docs/benchmarks.md (see bench_docs.py).
Figures are measured on this machine in this run; nothing is asserted.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

import bench_docs
import cv2
import numpy as np
from bench_lines import select_pairs

from sepfm_ros.evaluation.manifest import PairSpec, load_manifest
from sepfm_ros.evaluation.metrics import pose_errors, positives, run_metrics
from sepfm_ros.pipeline.compiled import warm_up
from sepfm_ros.pipeline.config import FEATURE_MAX_WIDTH
from sepfm_ros.pipeline.features import detection_factor
from sepfm_ros.pipeline.pipeline import Pipeline, PipelineConfig

REPO = Path(__file__).resolve().parent.parent
DATA = REPO.parent / "shared" / "data_lines"
BASELINES = ("small", "medium", "wide")


def node_grey(path: Path) -> np.ndarray:
    """A colour photograph as the node gets it from a bgr8 camera: one cvtColor to mono8."""
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise FileNotFoundError(path)
    return cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)


# The downscaled setting: these 1536 px frames detected by half, as 1080p is at the default.
HALF = 1280


def setting_label(max_width: int, width: int) -> str:
    """How images ``width`` px wide are detected under ``feature_max_width`` = ``max_width``."""
    factor = detection_factor(width, max_width)
    what = "full size" if factor == 1 else f"downscaled by {factor}"
    default = " (default)" if max_width == FEATURE_MAX_WIDTH else ""
    return f"feature_max_width {max_width}{default}: {what}"


def run_setting(
    pairs: list[PairSpec],
    data: Path,
    cams: dict,
    max_width: int,
    seeds: list[int],
    baseline: dict,
) -> tuple[list[dict], float]:
    """Every pair x seed through the pipeline with ``feature_max_width`` = ``max_width``: a row
    per run, and the features ms per detected image."""
    pipeline = Pipeline(PipelineConfig(feature_max_width=max_width), cache_size=len(cams) + 1)
    images: dict[Path, np.ndarray] = {}
    rows = []
    features_ms = 0.0
    t0 = time.time()
    for i, pair in enumerate(pairs):
        paths = (Path(pair.img_a), Path(pair.img_b))
        a, b = (images.setdefault(p, node_grey(p)) for p in paths)
        matched = pipeline.match(a, b, key_a=paths[0], key_b=paths[1])
        m = matched.matches
        features_ms += matched.timings_ms["features"]
        pos = positives(pair.F_gt, m.pts_a, m.pts_b)
        P_a, P_b = (np.asarray(cams[str(p.relative_to(data))], dtype=np.float64) for p in paths)
        for seed in seeds:
            seeded = replace(matched, config=replace(matched.config, seed=seed))
            result = pipeline.estimate(seeded)
            F = result.estimate.F
            met = run_metrics(F, m.pts_a, m.pts_b, pos, 1.0)
            rot, direction = pose_errors(F, m.pts_a, m.pts_b, P_a, P_b, 1.0)
            rows.append(
                {
                    "pair": pair.pair_id, "baseline": baseline[pair.pair_id],
                    "matches": len(m), "positives": int(pos.sum()), "f": met.f_score,
                    "ok": met.succeeded, "med": met.median_error if F is not None else np.inf,
                    "rot": rot, "dir": direction, "estimate_ms": result.timings_ms["estimate"],
                }
            )  # fmt: skip
        sys.stderr.write(f"\r  max width {max_width}: {i + 1}/{len(pairs)} pairs, "
                         f"{time.time() - t0:.0f} s")  # fmt: skip
    sys.stderr.write("\n")
    return rows, features_ms / max(1, pipeline.images_detected)


def table(settings: dict[str, list[dict]], features_ms: dict[str, float]) -> list[str]:
    out = [
        "| detection | matches per pair (median) | GT positives per pair (median) "
        "| F-score (mean ± sd) | success % | median GT-positive err px (median) "
        "| rotation err deg (median / p90) | translation-direction err deg (median / p90) "
        "| features ms per image (mean) | estimate ms per pair (median) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for label, rows in settings.items():
        f = np.array([r["f"] for r in rows])
        rot = [r["rot"] for r in rows]
        dirs = [r["dir"] for r in rows]
        med = [r["med"] for r in rows if r["positives"]]  # a pair without positives has none
        out.append(
            f"| {label} | {np.median([r['matches'] for r in rows]):.0f}"
            f" | {np.median([r['positives'] for r in rows]):.0f}"
            f" | {f.mean():.3f} ± {f.std():.3f} | {100 * np.mean([r['ok'] for r in rows]):.1f}"
            f" | {np.median(med):.3f}"
            f" | {np.median(rot):.2f} / {np.percentile(rot, 90):.2f}"
            f" | {np.median(dirs):.2f} / {np.percentile(dirs, 90):.2f}"
            f" | {features_ms[label]:.1f}"
            f" | {np.median([r['estimate_ms'] for r in rows]):.1f} |"
        )
    return out


def baseline_table(settings: dict[str, list[dict]]) -> list[str]:
    out = [
        "| detection | " + " | ".join(
            f"{b}: success % / rotation err deg (median)" for b in BASELINES
        ) + " |",
        "|---|" + "---|" * len(BASELINES),
    ]  # fmt: skip
    for label, rows in settings.items():
        cells = []
        for b in BASELINES:
            rs = [r for r in rows if r["baseline"] == b]
            if not rs:
                cells.append("n/a")
                continue
            success = 100 * np.mean([r["ok"] for r in rs])
            cells.append(f"{success:.1f} / {np.median([r['rot'] for r in rs]):.2f}")
        out.append(f"| {label} | " + " | ".join(cells) + " |")
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--max-pairs", type=int, default=0, help="evenly spaced pairs (0: all)")
    parser.add_argument("--seeds", default="0,1,2")
    parser.add_argument("--data", type=Path, default=DATA, help="the data_lines folder")
    parser.add_argument(
        "--write-docs", action="store_true", help="rewrite this section of docs/benchmarks.md"
    )
    parser.add_argument("--doc", type=Path, default=bench_docs.BENCH_DOC)
    args = parser.parse_args(argv)
    data = args.data
    if not data.is_dir():
        print(f"shared data not found at {data}", file=sys.stderr)
        return 2
    seeds = [int(s) for s in args.seeds.split(",")]
    all_pairs, _ = load_manifest(data / "pairs.json")
    pairs, note = select_pairs(all_pairs, args.max_pairs)
    raw = json.loads((data / "pairs.json").read_text())
    baseline = {p.pair_id: r.get("baseline", "") for p, r in zip(all_pairs, raw, strict=True)}
    cams = json.loads((data / "cameras.json").read_text())
    warm_up()  # compiling is not timed
    width = int(pairs[0].size_a[0]) if pairs[0].size_a else 1536
    with bench_docs.captured_stdout() as out:
        print(
            f"{note}; seeds {seeds}; {os.cpu_count()} CPUs, load average"
            f" {os.getloadavg()[0]:.1f} at the start."
        )
        print()
        settings, features_ms = {}, {}
        for max_width in (0, HALF):
            label = setting_label(max_width, width)
            settings[label], features_ms[label] = run_setting(
                pairs, data, cams, max_width, seeds, baseline
            )
        print("\n".join(table(settings, features_ms)))
        print()
        print("By baseline (parallax: small < 15 deg, medium 15-30 deg, wide >= 30 deg):")
        print()
        print("\n".join(baseline_table(settings)))
        print()
        print(f"Load average {os.getloadavg()[0]:.1f} at the end of the run.")
    if args.write_docs:
        title = "Native high-resolution frames, features at full size and downscaled"
        command = bench_docs.command_line("bench_downscale.py", argv)
        path = bench_docs.write_section(
            "bench_downscale",
            bench_docs.section("bench_downscale", title, command, out.text),
            args.doc,
        )
        print(f"wrote {path}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
