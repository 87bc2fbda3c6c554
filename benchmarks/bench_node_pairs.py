"""Benchmark: the pairs the live node sees, matched by the node's own pipeline, every method.

Pairs are consecutive frames of the two sequences of ../shared/data/cameras.json, as a camera in
motion gives them to the node: the left camera of ``kitti_seq2`` (frame k -> k+1, 1241x376, forward
motion, the epipole inside the image) and the ``templeRing`` views (view k -> k+1, 640x480); the
GT F of each pair comes from the two cameras (``fundamental_from_cameras``). Images are read as
the node gets them from a bag (the file's pixels, converted to mono8) and matched by
``Pipeline.match`` at the default ``PipelineConfig`` (ORB 1000 features, ratio 0.8), each frame
detected once as the node does in motion mode.

All methods then run on the same matches at threshold 1 px and confidence 0.99 (the node's
defaults), each with every seed. Printed per sequence and method: mean F-score against the GT
positives (matches within 1 px of the GT F), success % (median GT-positive error < 1 px and at
least 20 positives recovered, as bench_estimators.py), the share of runs whose median GT-positive
error is < 1 px alone, the median of the median GT-positive error, the rotation and
translation-direction errors (deg) of the pose taken from each F with the GT intrinsics
(``metrics.pose_errors``, as ``eval`` reports them: what a calibrated robot gets; a method
without F counts as 180 deg), median hypotheses and median ms per pair, and each method's
median ms over USAC_MAGSAC's in the same run; then per sequence the default method's compiled work
(numba kernels and OpenCV, ``compiled_work.py``) against the most time over USAC_MAGSAC's that
``REQUIRED_RATIO`` allows. Each method's timed runs on a pair follow an untimed run of it on the
same matches (``compiled_work.warm_up``), so none is timed right after another library's runs.

    python benchmarks/bench_node_pairs.py [--sequences kitti,temple] [--max-pairs N]
        [--seeds 0,1,2] [--methods a,b] [--write-docs [--doc FILE]]

``--write-docs`` rewrites this script's section of docs/benchmarks.md (see bench_docs.py).
Figures are measured on this machine in this run; nothing is asserted.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import bench_docs
import cv2
import numpy as np
from compiled_work import compiled_note, compiled_share, warm_up

from sepfm_ros.evaluation.methods import (
    REGISTRY,
    poselib_available,
    resolve_methods,
    superansac_methods,
)
from sepfm_ros.evaluation.metrics import (
    MIN_RECOVERED_POSITIVES,
    pose_errors,
    positives,
    run_metrics,
)
from sepfm_ros.geometry import DEFAULT_METHOD
from sepfm_ros.geometry.compiled import warm_up as warm_up_geometry
from sepfm_ros.geometry.epipolar import fundamental_from_cameras
from sepfm_ros.pipeline.features import Matches, to_gray
from sepfm_ros.pipeline.pipeline import Pipeline, PipelineConfig

REPO = Path(__file__).resolve().parent.parent
DATA = REPO.parent / "shared" / "data"
#: sequence name -> (label, prefix of its images in cameras.json)
SEQUENCES = {
    "kitti": (
        "KITTI seq 2 left, consecutive frames (forward motion), 1241x376",
        "kitti_seq2/left/",
    ),
    "temple": ("templeRing, consecutive views, 640x480", "templeRing/"),
}
#: the most median time over USAC_MAGSAC's the default method may take per sequence (issue 41's
#: required targets: half the ratios it was opened with), to set its compiled work against
REQUIRED_RATIO = {"kitti": 1.95, "temple": 1.5}
METHODS = [DEFAULT_METHOD] + [
    m for m in ("sep5", "ransac7", "cv-ransac", "cv-magsac", "cv-accurate") if m != DEFAULT_METHOD
]
if poselib_available():
    METHODS.append("poselib")
METHODS += superansac_methods()


@dataclass
class NodePair:
    """One consecutive pair, matched by the node's pipeline.

    Attributes:
        pair_id: "first image -> second image" (paths relative to the data folder).
        scene: the sequence key of :data:`SEQUENCES`.
        F_gt: (3, 3) GT F from the cameras, ``x_b^T F x_a = 0``.
        matches: the pipeline's matches (best first).
        size_a, size_b: (width, height).
        positives: (N,) bool, matches within 1 px of the GT F.
        P_a, P_b: (3, 4) the GT cameras (intrinsics and pose) of the two frames.
    """

    pair_id: str
    scene: str
    F_gt: np.ndarray
    matches: Matches
    size_a: tuple[int, int]
    size_b: tuple[int, int]
    positives: np.ndarray
    P_a: np.ndarray
    P_b: np.ndarray


def node_image(path: Path) -> np.ndarray:
    """The image as the node gets it: the file's pixels as a bag carries them, as mono8."""
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise FileNotFoundError(path)
    return to_gray(img)


def frames(data: Path, sequence: str) -> list[tuple[str, np.ndarray]]:
    """(image path relative to ``data``, 3x4 camera) of a sequence's frames, in order."""
    cams = json.loads((data / "cameras.json").read_text())
    prefix = SEQUENCES[sequence][1]
    keys = sorted(k for k in cams if k.startswith(prefix))
    return [(k, np.asarray(cams[k], dtype=np.float64)) for k in keys]


def node_pairs(
    sequence: str, data: Path = DATA, max_pairs: int = 0, progress: bool = True
) -> list[NodePair]:
    """The consecutive pairs of ``sequence`` (all, or ``max_pairs`` evenly spaced ones), matched
    by ``Pipeline.match`` at the default ``PipelineConfig``."""
    seq = frames(data, sequence)
    idx = list(range(len(seq) - 1))
    if max_pairs and max_pairs < len(idx):
        idx = sorted(set(np.linspace(0, len(idx) - 1, max_pairs).round().astype(int).tolist()))
    pipeline = Pipeline(PipelineConfig())
    out = []
    for j, i in enumerate(idx):
        (ka, Pa), (kb, Pb) = seq[i], seq[i + 1]
        img_a, img_b = node_image(data / ka), node_image(data / kb)
        m = pipeline.match(img_a, img_b, key_a=ka, key_b=kb).matches
        F = fundamental_from_cameras(Pa, Pb)
        size_a = (img_a.shape[1], img_a.shape[0])
        size_b = (img_b.shape[1], img_b.shape[0])
        pos = positives(F, m.pts_a, m.pts_b)
        out.append(NodePair(f"{ka} -> {kb}", sequence, F, m, size_a, size_b, pos, Pa, Pb))
        if progress:
            sys.stderr.write(f"\r  {sequence}: matched {j + 1}/{len(idx)} pairs")
    if progress:
        sys.stderr.write("\n")
    return out


def score(F: np.ndarray | None, pair: NodePair, threshold: float = 1.0) -> dict:
    """F-score, median GT-positive error and success of one estimate on ``pair``, and the
    rotation and translation-direction errors (deg) of the pose a calibrated robot takes from
    it (``metrics.pose_errors``: F's inliers, the GT intrinsics)."""
    m = pair.matches
    met = run_metrics(F, m.pts_a, m.pts_b, pair.positives, threshold)
    med = met.median_error if F is not None else np.inf
    below = bool(np.isfinite(med) and med < 1.0)
    rot, direction = pose_errors(F, m.pts_a, m.pts_b, pair.P_a, pair.P_b, threshold)
    return {
        "f": met.f_score, "med": med, "below": below, "ok": met.succeeded,
        "rot": rot, "dir": direction,
    }  # fmt: skip


def evaluable(pair: NodePair) -> bool:
    """The pair has enough GT positives to be scored (metrics.MIN_RECOVERED_POSITIVES)."""
    return int(np.count_nonzero(pair.positives)) >= MIN_RECOVERED_POSITIVES


def run_methods(pairs: list[NodePair], methods: list[str], seeds: list[int]) -> dict:
    """Every method x seed on every pair: {method: [row per run]}."""
    rows: dict[str, list[dict]] = {m: [] for m in methods}
    t0 = time.time()
    for i, pair in enumerate(pairs):
        m = pair.matches
        for name in methods:
            warm_up(REGISTRY[name].run, m.pts_a, m.pts_b, pair.size_a, pair.size_b, 1.0, 0.99, 0)
            for seed in seeds:
                args = (m.pts_a, m.pts_b, pair.size_a, pair.size_b, 1.0, 0.99, seed)
                r = REGISTRY[name].run(*args)
                row = {**score(r.F, pair), "hyp": r.hypotheses, "ms": r.ms}
                if name == DEFAULT_METHOD:  # its compiled work (a profiled run of the same)
                    row["compiled"] = compiled_share(partial(REGISTRY[name].run, *args)) * r.ms
                rows[name].append(row)
        sys.stderr.write(
            f"\r  {pairs[0].scene}: estimated {i + 1}/{len(pairs)} pairs, {time.time() - t0:.0f} s"
        )
    sys.stderr.write("\n")
    return rows


def table(rows: dict, methods: list[str]) -> list[str]:
    magsac = float(np.median([r["ms"] for r in rows["cv-magsac"]])) if "cv-magsac" in rows else 0
    out = [
        "| method | F-score (mean ± sd) | success % | median err < 1 px % | median GT-inlier err "
        "px (median) | rotation err deg (median) | translation-direction err deg (median / p90) "
        "| hypotheses (median) | ms per pair (median) | ms / cv-magsac |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name in methods:
        rs = rows[name]
        f = np.array([r["f"] for r in rs])
        hyp = [r["hyp"] for r in rs if r["hyp"] is not None]
        ms = float(np.median([r["ms"] for r in rs]))
        rot = [r["rot"] for r in rs]
        dirs = [r["dir"] for r in rs]
        label = f"{name} (default)" if name == DEFAULT_METHOD else name
        out.append(
            f"| {label} | {f.mean():.3f} ± {f.std():.3f}"
            f" | {100 * np.mean([r['ok'] for r in rs]):.1f}"
            f" | {100 * np.mean([r['below'] for r in rs]):.1f}"
            f" | {np.median([r['med'] for r in rs]):.3f}"
            f" | {np.median(rot):.3f} | {np.median(dirs):.2f} / {np.percentile(dirs, 90):.2f}"
            f" | {f'{np.median(hyp):.0f}' if hyp else 'n/a'} | {ms:.1f}"
            f" | {f'{ms / magsac:.2f}' if magsac > 0 else 'n/a'} |"
        )
    return out


def report(sequence: str, pairs: list[NodePair], rows: dict, methods: list[str], seeds) -> str:
    n = np.array([len(p.matches) for p in pairs])
    inl = np.array([p.positives.mean() if len(p.positives) else 0.0 for p in pairs])
    ev = [evaluable(p) for p in pairs]
    skipped = [p.pair_id for p, e in zip(pairs, ev, strict=True) if not e]
    keep = np.repeat(ev, len(seeds))
    rows = {m: [r for r, k in zip(rs, keep, strict=True) if k] for m, rs in rows.items()}
    out = [
        f"**{SEQUENCES[sequence][0]}**: {len(pairs)} pairs x {len(seeds)} seeds; matches per pair"
        f" median {np.median(n):.0f} (min {n.min()}); share within 1 px of the GT F: median "
        f"{np.median(inl):.2f}, min {inl.min():.2f}. "
        + (
            f"Scored on the {sum(ev)} pairs with >= {MIN_RECOVERED_POSITIVES} GT inliers; left out"
            f" (fewer): {', '.join(skipped)}."
            if skipped
            else f"Every pair has >= {MIN_RECOVERED_POSITIVES} GT inliers."
        ),
        "",
        *table(rows, methods),
        "",
    ]
    if DEFAULT_METHOD in rows and "cv-magsac" in rows and rows[DEFAULT_METHOD]:
        own = rows[DEFAULT_METHOD]
        magsac = float(np.median([r["ms"] for r in rows["cv-magsac"]]))
        note = compiled_note(
            [r["compiled"] for r in own], [r["ms"] for r in own], magsac, REQUIRED_RATIO[sequence]
        )
        out += [note, ""]
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", type=Path, default=DATA, help=argparse.SUPPRESS)
    ap.add_argument(
        "--sequences", default=",".join(SEQUENCES), help=f"comma list of {list(SEQUENCES)}"
    )
    ap.add_argument(
        "--max-pairs", type=int, default=0, help="evenly spaced pairs per sequence (0: all)"
    )
    ap.add_argument("--seeds", default="0,1,2", help="comma-separated seeds")
    ap.add_argument("--methods", default=",".join(METHODS), help="comma list (evaluation names)")
    ap.add_argument("--write-docs", action="store_true")
    ap.add_argument("--doc", type=Path, default=bench_docs.BENCH_DOC, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if not (a.data / "cameras.json").is_file():
        print(f"shared data not found at {a.data}", file=sys.stderr)
        return 2
    sequences = [s for s in a.sequences.split(",") if s]
    bad = [s for s in sequences if s not in SEQUENCES]
    try:
        if bad or not sequences:
            raise ValueError(f"unknown sequences {bad}; known: {list(SEQUENCES)}")
        methods = [m.name for m in resolve_methods(a.methods)]
    except ValueError as e:
        print(e, file=sys.stderr)
        return 2
    seeds = [int(s) for s in a.seeds.split(",")]
    print(f"warm-up {warm_up_geometry():.1f} s", file=sys.stderr)
    texts = []
    for s in sequences:
        pairs = node_pairs(s, a.data, a.max_pairs)
        rows = run_methods(pairs, methods, seeds)
        texts.append(report(s, pairs, rows, methods, seeds))
        print(texts[-1], flush=True)
    title = "Node pipeline on consecutive frames (ORB 1000, ratio 0.8, threshold 1 px)"
    if a.write_docs:
        head = (
            "The pairs the live node sees in motion mode, matched by `Pipeline.match` at the "
            "default `PipelineConfig`; every method on the same matches, threshold 1 px, "
            f"confidence 0.99, seeds {seeds}. Success: median GT-inlier error < 1 px and >= 20 "
            "GT inliers recovered; *median err < 1 px* drops the second condition (the issue's "
            "measure). Rotation and translation-direction errors: the relative pose taken from "
            "each method's F with the GT intrinsics (`metrics.pose_errors`, as `eval` reports it; "
            "what a calibrated robot gets), p90 over runs. Default method at run time: "
            f"{DEFAULT_METHOD}."
        )
        command = bench_docs.command_line("bench_node_pairs.py", argv)
        body = "\n\n".join([head, *texts])
        path = bench_docs.write_section(
            "bench_node_pairs", bench_docs.section("bench_node_pairs", title, command, body), a.doc
        )
        print(f"wrote {path}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
