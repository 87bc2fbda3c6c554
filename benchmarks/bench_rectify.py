"""Benchmark: uncalibrated stereo rectification (``sepfm_ros rectify``) on pairs that are not
rectified, against OpenCV's own pipeline on the same matches.

Pairs:

- ``rotated``: the shared rectified stereo pairs (KITTI left/right, Tsukuba) with the right
  image warped by K R K^-1, R a rotation by a known angle about the axis (1, 1, 1)/sqrt(3)
  (pitch, yaw and roll at once); K from ``cameras.json`` (KITTI) or a focal of the image width
  with the principal point at the centre (Tsukuba, which has no cameras). One row per angle.
- ``templeRing``: every 4th calibrated pair of ``../shared/data`` (turntable views).
- ``data_lines``: every 8th pair of ``../shared/data_lines`` (Strecha facades; wide baselines,
  some epipoles inside the image, which the rectifier refuses).

Matches: the pipeline's SIFT (2000 features, ratio 0.8), once per pair. Measured on the same
matches for every column: the matches within 1 px (symmetric epipolar distance) of the
ground-truth F, so no method is scored on its own inlier set. Per pair, the median
|v_a - v_b| of those matches (px); per row, the median over the pairs rectified.

- ``before``: in the input images;
- ``sep4``: the default estimator (1 px), then :func:`rectify_uncalibrated` on its inliers
  (OpenCV's ``stereoRectifyUncalibrated`` with the checks and framing of
  ``sepfm_ros.pipeline.rectification``);
- ``MAGSAC``: OpenCV's ``findFundamentalMat`` USAC_MAGSAC (1 px, confidence 0.99) on the same
  matches, then the same :func:`rectify_uncalibrated` on its inliers;
- ``OpenCV raw``: OpenCV's pipeline alone, MAGSAC's F into ``stereoRectifyUncalibrated`` with no
  checks and no framing (its homographies as returned; a pair it cannot rectify gives the large
  figures the table shows).

    python benchmarks/bench_rectify.py [--write-docs] [--angles 0.5 1 2 4]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_docs  # noqa: E402

from sepfm_ros.geometry import symmetric_epipolar_distance  # noqa: E402
from sepfm_ros.pipeline.pipeline import Pipeline, PipelineConfig  # noqa: E402
from sepfm_ros.pipeline.rectification import (  # noqa: E402
    RectificationError,
    rectify_uncalibrated,
    vertical_disparity,
)

REPO = Path(__file__).resolve().parent.parent
DATA = REPO.parent / "shared" / "data"
DATA_LINES = REPO.parent / "shared" / "data_lines"
TARGET_PX = 0.5
GT_PX = 1.0  # a match within this of the ground-truth F is measured
AXIS = np.ones(3) / np.sqrt(3.0)
CONFIG = PipelineConfig(features="sift", max_features=2000, ratio=0.8, seed=0)
COLUMNS = ("before", "sep4", "MAGSAC", "OpenCV raw")


@dataclass
class Case:
    """One pair to rectify: images (H, W) uint8, the ground-truth F (x_b^T F x_a = 0)."""

    image_a: np.ndarray
    image_b: np.ndarray
    F: np.ndarray


@dataclass
class Row:
    """Per-pair medians (px) by column, and the refusals by column and kind."""

    name: str
    figures: dict[str, list[float]] = field(default_factory=lambda: {c: [] for c in COLUMNS})
    refused: dict[str, Counter] = field(default_factory=lambda: {c: Counter() for c in COLUMNS})
    pairs: int = 0


def rotation(deg: float) -> np.ndarray:
    """(3, 3) rotation by ``deg`` degrees about AXIS."""
    return cv2.Rodrigues(AXIS * np.deg2rad(deg))[0]


def intrinsics(cams: dict, key: str, size: tuple[int, int]) -> np.ndarray:
    """(3, 3) K of image ``key``: from its camera in ``cams``, else focal = width, centred."""
    if key in cams:
        K = cv2.decomposeProjectionMatrix(np.asarray(cams[key], dtype=np.float64))[0]
        return K / K[2, 2]
    w, h = size
    return np.array([[w, 0.0, (w - 1) / 2], [0.0, w, (h - 1) / 2], [0.0, 0.0, 1.0]])


def rotated_case(entry: dict, cams: dict, deg: float) -> Case:
    """A shared stereo pair with its right image warped by H = K R K^-1 (R: ``deg`` about AXIS);
    F becomes H^-T F."""
    a = cv2.imread(str(DATA / entry["img_a"]), cv2.IMREAD_GRAYSCALE)
    b = cv2.imread(str(DATA / entry["img_b"]), cv2.IMREAD_GRAYSCALE)
    size = (b.shape[1], b.shape[0])
    K = intrinsics(cams, entry["img_b"], size)
    H = K @ rotation(deg) @ np.linalg.inv(K)
    b_rot = cv2.warpPerspective(b, H, size, flags=cv2.INTER_LINEAR)
    F = np.linalg.inv(H).T @ np.asarray(entry["F"], dtype=np.float64)
    return Case(a, b_rot, F / np.linalg.norm(F))


def real_case(root: Path, entry: dict) -> Case:
    """A shared calibrated pair as stored."""
    a = cv2.imread(str(root / entry["img_a"]), cv2.IMREAD_GRAYSCALE)
    b = cv2.imread(str(root / entry["img_b"]), cv2.IMREAD_GRAYSCALE)
    return Case(a, b, np.asarray(entry["F"], dtype=np.float64))


def _median_vd(H_a: np.ndarray, H_b: np.ndarray, pa: np.ndarray, pb: np.ndarray) -> float:
    return float(np.median(vertical_disparity(H_a, H_b, pa, pb)))


def measure(case: Case, pipeline: Pipeline, row: Row) -> None:
    """Add one pair's figures to ``row``."""
    result = pipeline.process(case.image_a, case.image_b)
    m = result.matches
    size_a, size_b = result.size_a, result.size_b
    gt = symmetric_epipolar_distance(case.F, m.pts_a, m.pts_b) < GT_PX
    row.pairs += 1
    if gt.sum() < 8:
        for c in COLUMNS:
            row.refused[c]["no ground-truth matches"] += 1
        return
    pa, pb = m.pts_a[gt], m.pts_b[gt]
    row.figures["before"].append(_median_vd(np.eye(3), np.eye(3), pa, pb))
    F_cv, mask = cv2.findFundamentalMat(m.pts_a, m.pts_b, cv2.USAC_MAGSAC, GT_PX, 0.99)
    estimates = {"sep4": (result.estimate.F, result.estimate.inliers)}
    if F_cv is not None and F_cv.shape == (3, 3):
        estimates["MAGSAC"] = (F_cv, mask.ravel().astype(bool))
    for column in ("sep4", "MAGSAC"):
        if column not in estimates or estimates[column][0] is None:
            row.refused[column]["no F"] += 1
            continue
        F, inl = estimates[column]
        try:
            rect = rectify_uncalibrated(F, m.pts_a[inl], m.pts_b[inl], size_a, size_b)
        except RectificationError as exc:
            row.refused[column][exc.kind] += 1
            continue
        row.figures[column].append(_median_vd(rect.H_a, rect.H_b, pa, pb))
    if "MAGSAC" not in estimates:
        row.refused["OpenCV raw"]["no F"] += 1
        return
    F, inl = estimates["MAGSAC"]
    ok, H1, H2 = cv2.stereoRectifyUncalibrated(m.pts_a[inl], m.pts_b[inl], F, size_b)
    if not ok:
        row.refused["OpenCV raw"]["failed"] += 1
        return
    row.figures["OpenCV raw"].append(_median_vd(H1, H2, pa, pb))


def _fmt(values: list[float]) -> str:
    return f"{np.median(values):.2f}" if values else "n/a"


def _under(values: list[float]) -> str:
    return f"{sum(v < TARGET_PX for v in values)}/{len(values)}" if values else "0/0"


def _refusals(counter: Counter) -> str:
    return ", ".join(f"{k} {n}" for k, n in sorted(counter.items())) or "-"


def table(rows: list[Row]) -> str:
    """The markdown table of ``rows``."""
    head = (
        "| pairs | n | before (px) | sep4 (px) | sep4 under 0.5 px | MAGSAC (px) "
        "| MAGSAC under 0.5 px | OpenCV raw (px) | sep4 / MAGSAC | refused: sep4; MAGSAC |"
    )
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for r in rows:
        s, c = r.figures["sep4"], r.figures["MAGSAC"]
        ratio = f"{np.median(s) / np.median(c):.2f}" if s and c and np.median(c) > 0 else "n/a"
        lines.append(
            f"| {r.name} | {r.pairs} | {_fmt(r.figures['before'])} | {_fmt(s)} | {_under(s)} "
            f"| {_fmt(c)} | {_under(c)} | {_fmt(r.figures['OpenCV raw'])} | {ratio} "
            f"| {_refusals(r.refused['sep4'])}; {_refusals(r.refused['MAGSAC'])} |"
        )
    return "\n".join(lines)


def run(angles: list[float], temple_step: int, lines_step: int, stereo_step: int = 1) -> list[Row]:
    """Measure every set (every ``*_step``-th pair of each); print progress to stderr."""
    pipeline = Pipeline(CONFIG)
    pairs = json.loads((DATA / "pairs.json").read_text())
    cams = json.loads((DATA / "cameras.json").read_text())
    stereo = [p for p in pairs if p["baseline"] == "stereo"][::stereo_step]
    rows = []
    for deg in angles:
        row = Row(f"stereo, right rotated {deg:g} deg")
        for entry in stereo:
            measure(rotated_case(entry, cams, deg), pipeline, row)
        rows.append(row)
        print(f"{row.name}: {row.pairs} pairs", file=sys.stderr)
    temple = [p for p in pairs if p["scene"] == "templeRing"][::temple_step]
    row = Row(f"templeRing, every {temple_step}th pair")
    for entry in temple:
        measure(real_case(DATA, entry), pipeline, row)
    rows.append(row)
    lines = json.loads((DATA_LINES / "pairs.json").read_text())[::lines_step]
    row = Row(f"data_lines (Strecha), every {lines_step}th pair")
    for entry in lines:
        measure(real_case(DATA_LINES, entry), pipeline, row)
    rows.append(row)
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--angles", type=float, nargs="+", default=[0.5, 1.0, 2.0, 4.0])
    ap.add_argument("--temple-step", type=int, default=4)
    ap.add_argument("--lines-step", type=int, default=8)
    ap.add_argument("--stereo-step", type=int, default=1)
    ap.add_argument("--doc", type=Path, default=bench_docs.BENCH_DOC)
    ap.add_argument("--write-docs", action="store_true", help="rewrite its docs section")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    rows = run(args.angles, args.temple_step, args.lines_step, args.stereo_step)
    text = (
        f"Median over pairs of the median |vertical disparity| (px) of the matches within "
        f"{GT_PX:g} px of the ground-truth F (the same matches for every column; SIFT 2000, "
        f"ratio 0.8, seed 0), target under {TARGET_PX} px. `sep4` and `MAGSAC`: that F and its "
        "inliers into `rectify_uncalibrated` (OpenCV's stereoRectifyUncalibrated with the "
        "package's checks and framing); `OpenCV raw`: MAGSAC's F into "
        "stereoRectifyUncalibrated as returned, no checks. Rotated pairs: "
        f"{rows[0].pairs if args.angles else 0} shared stereo pairs (KITTI, Tsukuba) with the "
        "right image warped by K R K^-1, R about "
        "(1, 1, 1)/sqrt(3). Refused: the rectifier's error kind (e.g. an epipole inside an "
        f"image).\n\n{table(rows)}\n\n{time.perf_counter() - t0:.0f} s."
    )
    print(text)
    if args.write_docs:
        command = bench_docs.command_line("bench_rectify.py", argv)
        section = bench_docs.section(
            "bench_rectify", "Uncalibrated stereo rectification (sepfm_ros rectify)", command, text
        )
        path = bench_docs.write_section("bench_rectify", section, args.doc)
        print(f"wrote {path}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
