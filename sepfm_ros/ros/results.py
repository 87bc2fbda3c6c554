"""Read the node's outputs back from a bag and score them against the bag's ground truth.

Used by ``process`` (its summary), ``demo`` (the per-frame table) and the replay tests (live vs
offline). The error against ground truth is the one of the node tests and the evaluation: the
median symmetric epipolar distance, under the estimated F, of the matches that are within
``GT_INLIER_PX`` (1 px) of the ground-truth F ("positives", from the ``~/matches`` cloud).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import Image, PointCloud2

from sepfm_ros.geometry import symmetric_epipolar_distance
from sepfm_ros.ros.bags.reader import BagReader
from sepfm_ros.ros.bags.types import GROUND_TRUTH_TOPIC, format_stamp
from sepfm_ros.ros.messages import (
    ESTIMATE_STATUS_NAME,
    fundamental_from_image,
    matches_from_pointcloud2,
    stamp_ns,
    status_values,
)

GT_INLIER_PX = 1.0
OUTPUT_NAMESPACE = "/sepfm"


def output_topics(namespace: str = OUTPUT_NAMESPACE) -> dict[str, str]:
    """kind -> topic of the node's outputs under ``namespace`` (the node's ``~``)."""
    ns = namespace.rstrip("/")
    return {
        "fundamental": f"{ns}/fundamental",
        "matches": f"{ns}/matches",
        "estimate_info": f"{ns}/estimate_info",
    }


def calibrated_topics(namespace: str = OUTPUT_NAMESPACE) -> dict[str, str]:
    """kind -> topic of the node's outputs with camera_info (pose and calibration check)."""
    ns = namespace.rstrip("/")
    return {
        "relative_transform": f"{ns}/relative_transform",
        "calibration_check": f"{ns}/calibration_check",
    }


def gt_error_px(F: np.ndarray, F_gt: np.ndarray, pts_a: np.ndarray, pts_b: np.ndarray) -> float:
    """Median symmetric epipolar distance (px) under F of the matches within 1 px of F_gt.

    pts_a, pts_b: (N, 2) pixels. NaN when no match is within 1 px of the ground truth.
    """
    if len(pts_a) == 0:
        return float("nan")
    pos = symmetric_epipolar_distance(F_gt, pts_a, pts_b) < GT_INLIER_PX
    if not np.any(pos):
        return float("nan")
    return float(np.median(symmetric_epipolar_distance(F, pts_a[pos], pts_b[pos])))


def run_label(run: int) -> str:
    """How a pass after ``run`` restarts of the pairing is marked: "#2", "#3", ...; "" for the
    first (a looped bag's later passes keep the stamps of the first)."""
    return f"#{run + 1}" if run else ""


@dataclass
class FrameResult:
    """The node's outputs for one stamp (the newer image's stamp)."""

    stamp_ns: int
    run: int = 0  # the input's stamps jumped back this many times before it (a looped bag)
    F: np.ndarray | None = None
    cloud: np.ndarray | None = None  # structured MATCH_DTYPE array
    info: dict[str, str] = field(default_factory=dict)
    F_gt: np.ndarray | None = None

    @property
    def run_label(self) -> str:
        """ "#2", "#3", ... for the passes after a restart of the pairing; "" for the first."""
        return run_label(self.run)

    @property
    def matches(self) -> int:
        return int(self.info.get("matches", len(self.cloud) if self.cloud is not None else 0))

    @property
    def inliers(self) -> int:
        return int(self.info.get("inliers", 0))

    @property
    def hypotheses(self) -> int:
        return int(self.info.get("hypotheses", 0))

    @property
    def status(self) -> str:
        return self.info.get("status", "no info")

    def pts(self) -> tuple[np.ndarray, np.ndarray]:
        if self.cloud is None or len(self.cloud) == 0:
            return np.zeros((0, 2)), np.zeros((0, 2))
        c = self.cloud
        pts_a = np.stack([c["u_a"], c["v_a"]], axis=1).astype(np.float64)
        pts_b = np.stack([c["u_b"], c["v_b"]], axis=1).astype(np.float64)
        return pts_a, pts_b

    @property
    def error_px(self) -> float:
        """Error against ground truth (see the module docstring); NaN without F or GT."""
        if self.F is None or self.F_gt is None:
            return float("nan")
        return gt_error_px(self.F, self.F_gt, *self.pts())


def read_results(
    bag: str | Path, namespace: str = OUTPUT_NAMESPACE, gt_bag: str | Path | None = None
) -> list[FrameResult]:
    """Per-pair outputs found in ``bag`` (by run, then stamp), with GT from ``gt_bag`` or ``bag``.

    The node and ``process`` publish each output topic's pairs in increasing stamp order; a
    stamp at or before the topic's previous one means they restarted their pairing (a looped
    bag, a restarted driver) and starts a new run, so the passes of a looped bag stay apart.
    """
    topics = output_topics(namespace)
    frames: dict[tuple[int, int], FrameResult] = {}
    runs: dict[str, tuple[int, int]] = {}  # topic -> (run, previous stamp)

    def frame(topic: str, stamp: int) -> FrameResult:
        run, previous = runs.get(topic, (0, stamp - 1))
        if stamp <= previous:
            run += 1
        runs[topic] = (run, stamp)
        return frames.setdefault((run, stamp), FrameResult(stamp, run))

    with BagReader(bag) as reader:
        wanted = [t for t in topics.values() if t in reader.topics]
        for msg in reader.messages(wanted):
            if msg.topic == topics["fundamental"]:
                m = deserialize_message(msg.data, Image)
                frame(msg.topic, stamp_ns(m.header.stamp)).F = fundamental_from_image(m)
            elif msg.topic == topics["matches"]:
                m = deserialize_message(msg.data, PointCloud2)
                frame(msg.topic, stamp_ns(m.header.stamp)).cloud = matches_from_pointcloud2(m)
            else:
                m = deserialize_message(msg.data, DiagnosticArray)
                for st in m.status:
                    if st.name == ESTIMATE_STATUS_NAME:
                        frame(msg.topic, stamp_ns(m.header.stamp)).info = status_values(st)
    gt = read_ground_truth(gt_bag if gt_bag is not None else bag)
    for (_, stamp), fr in frames.items():
        if stamp in gt:
            fr.F_gt = gt[stamp]
    return [frames[k] for k in sorted(frames)]


def read_ground_truth(bag: str | Path) -> dict[int, np.ndarray]:
    """stamp (ns) -> GT F of the bag's ``/ground_truth/fundamental`` (empty when absent)."""
    out: dict[int, np.ndarray] = {}
    with BagReader(bag) as reader:
        if GROUND_TRUTH_TOPIC not in reader.topics:
            return out
        for msg in reader.messages([GROUND_TRUTH_TOPIC]):
            m = deserialize_message(msg.data, Image)
            out[stamp_ns(m.header.stamp)] = fundamental_from_image(m)
    return out


def _fmt_err(e: float) -> str:
    return "-" if math.isnan(e) else f"{e:.3f}"


def format_table(results: list[FrameResult]) -> str:
    """A per-frame text table: stamp, matches, inliers, hypotheses, error vs GT, status."""
    head = f"{'stamp':>21} {'matches':>7} {'inliers':>7} {'hyps':>6} {'F':>3} {'err_px':>7}  status"
    rows = [head, "-" * len(head)]
    for r in results:
        rows.append(
            f"{f'{format_stamp(r.stamp_ns)} {r.run_label}'.rstrip():>21} "
            f"{r.matches:>7d} {r.inliers:>7d} "
            f"{r.hypotheses:>6d} {'yes' if r.F is not None else 'no':>3} "
            f"{_fmt_err(r.error_px):>7}  {r.status}"
        )
    return "\n".join(rows)


@dataclass(frozen=True)
class Summary:
    """Totals over a run: frames with output, frames with F, GT-scored frames and errors."""

    frames: int
    with_f: int
    with_gt: int
    median_error_px: float
    max_error_px: float
    success_rate: float  # frames with F and GT error < 1 px, over frames with GT


def summarize(results: list[FrameResult], expected_frames: int | None = None) -> Summary:
    n = expected_frames if expected_frames is not None else len(results)
    errors = [r.error_px for r in results if r.F_gt is not None]
    finite = [e for e in errors if not math.isnan(e)]
    n_gt = len(errors)
    ok = sum(1 for e in finite if e < 1.0)
    return Summary(
        frames=n,
        with_f=sum(1 for r in results if r.F is not None),
        with_gt=n_gt,
        median_error_px=float(np.median(finite)) if finite else float("nan"),
        max_error_px=float(np.max(finite)) if finite else float("nan"),
        success_rate=ok / n_gt if n_gt else float("nan"),
    )


def format_summary(s: Summary) -> str:
    text = f"{s.with_f}/{s.frames} frame pairs with F"
    if s.with_gt:
        text += (
            f"; against ground truth ({s.with_gt} pairs): median error "
            f"{_fmt_err(s.median_error_px)} px, max {_fmt_err(s.max_error_px)} px, "
            f"success (< 1 px) {100 * s.success_rate:.0f}%"
        )
    return text
