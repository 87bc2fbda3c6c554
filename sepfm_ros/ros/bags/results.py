"""Read the node's outputs back from a bag and score them against the bag's ground truth.

Used by ``process`` (its summary), ``demo`` (the per-frame table and the calibration check) and
the replay tests (live vs offline). The node's answers are typed (``sepfm_msgs/TwoViewEstimate``
on ``~/estimate``, ``sepfm_msgs/MatchArray`` on ``~/matches``). The error against ground truth
is the one of the node tests and the evaluation: the median symmetric epipolar distance, under
the estimated F, of the matches that are within ``GT_INLIER_PX`` (1 px) of the ground-truth F
("positives", from ``~/matches``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import Image

from sepfm_msgs.msg import MatchArray, TwoViewEstimate
from sepfm_ros.geometry import symmetric_epipolar_distance
from sepfm_ros.ros.bags.reader import BagReader
from sepfm_ros.ros.bags.types import (
    DIAGNOSTIC_ARRAY,
    DIAGNOSTIC_STATUS,
    GROUND_TRUTH_TOPIC,
    format_stamp,
)
from sepfm_ros.ros.msgs.calibration import calibration_check_statuses
from sepfm_ros.ros.msgs.fundamental import fundamental_from_image, fundamental_from_msg
from sepfm_ros.ros.msgs.headers import stamp_ns

GT_INLIER_PX = 1.0
OUTPUT_NAMESPACE = "/sepfm"


def output_topics(namespace: str = OUTPUT_NAMESPACE) -> dict[str, str]:
    """kind -> topic of the node's outputs under ``namespace`` (the node's ``~``)."""
    ns = namespace.rstrip("/")
    return {
        "estimate": f"{ns}/estimate",
        "matches": f"{ns}/matches",
    }


def calibrated_topics(namespace: str = OUTPUT_NAMESPACE) -> dict[str, str]:
    """kind -> topic of the node's outputs with camera_info (pose outputs and calibration
    check): ``relative_transform`` and ``relative_pose`` of a stereo rig, ``angular_velocity``
    and ``translation_direction`` of a moving camera."""
    ns = namespace.rstrip("/")
    kinds = (
        "relative_transform",
        "relative_pose",
        "angular_velocity",
        "translation_direction",
        "calibration_check",
    )
    return {kind: f"{ns}/{kind}" for kind in kinds}


@dataclass(frozen=True)
class CalibrationCheck:
    """One ``~/calibration_check`` message of a bag: its pair's stamp (ns; None in a bag of
    sepfm_ros 0.1.0, whose bare DiagnosticStatus had no header), log time (ns) and status."""

    stamp_ns: int | None
    log_time_ns: int
    status: DiagnosticStatus


def read_calibration_checks(
    bag: str | Path, namespace: str = OUTPUT_NAMESPACE
) -> list[CalibrationCheck]:
    """The calibration checks in ``bag`` (written by ``process`` or recorded from the node), in
    log-time order; empty without the topic. Reads both types the topic has had: the stamped
    ``diagnostic_msgs/DiagnosticArray`` and the bare ``DiagnosticStatus`` of sepfm_ros 0.1.0."""
    topic = calibrated_topics(namespace)["calibration_check"]
    out: list[CalibrationCheck] = []
    with BagReader(bag) as reader:
        if topic not in reader.topics:
            return out
        info = reader.require(topic, (DIAGNOSTIC_ARRAY, DIAGNOSTIC_STATUS))
        stamped = info.msgtype == DIAGNOSTIC_ARRAY
        for raw in reader.messages([topic]):
            msg = deserialize_message(raw.data, DiagnosticArray if stamped else DiagnosticStatus)
            stamp = stamp_ns(msg.header.stamp) if stamped else None
            for status in calibration_check_statuses(msg):
                out.append(CalibrationCheck(stamp, raw.log_time_ns, status))
    return out


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


MATCH_TABLE_DTYPE = np.dtype(
    [
        ("u_a", "f8"),
        ("v_a", "f8"),
        ("u_b", "f8"),
        ("v_b", "f8"),
        ("error_px", "f8"),
        ("inlier", "?"),
        ("on_line", "?"),
    ]
)


def match_table(msg: MatchArray) -> np.ndarray:
    """A MatchArray's matches as a structured (N,) array of MATCH_TABLE_DTYPE (the fields of
    sepfm_msgs/Match)."""
    rows = [(m.u_a, m.v_a, m.u_b, m.v_b, m.error_px, m.inlier, m.on_line) for m in msg.matches]
    return np.array(rows, dtype=MATCH_TABLE_DTYPE)


@dataclass
class FrameResult:
    """The node's answer for one stamp (the output header's stamp): its TwoViewEstimate and
    its matches (a MATCH_TABLE_DTYPE array)."""

    stamp_ns: int
    run: int = 0  # the input's stamps jumped back this many times before it (a looped bag)
    estimate: TwoViewEstimate | None = None
    match_rows: np.ndarray | None = None
    F_gt: np.ndarray | None = None

    @property
    def run_label(self) -> str:
        """ "#2", "#3", ... for the passes after a restart of the pairing; "" for the first."""
        return run_label(self.run)

    @property
    def F(self) -> np.ndarray | None:
        """The answer's F (3, 3), None without one."""
        if self.estimate is None or not self.estimate.has_f:
            return None
        return fundamental_from_msg(self.estimate)

    @property
    def matches(self) -> int:
        if self.estimate is not None:
            return int(self.estimate.matches)
        return len(self.match_rows) if self.match_rows is not None else 0

    @property
    def inliers(self) -> int:
        return int(self.estimate.inliers) if self.estimate is not None else 0

    @property
    def hypotheses(self) -> int:
        return int(self.estimate.hypotheses) if self.estimate is not None else 0

    @property
    def line_search_skipped(self) -> bool:
        """The estimator skipped its line search (the escape; False in bags of 0.1.0)."""
        return bool(self.estimate.line_search_skipped) if self.estimate is not None else False

    @property
    def status(self) -> str:
        return self.estimate.status_text if self.estimate is not None else "no estimate"

    def pts(self) -> tuple[np.ndarray, np.ndarray]:
        """(N, 2) pixels of the matches in image a and image b."""
        if self.match_rows is None or len(self.match_rows) == 0:
            return np.zeros((0, 2)), np.zeros((0, 2))
        c = self.match_rows
        pts_a = np.stack([c["u_a"], c["v_a"]], axis=1)
        pts_b = np.stack([c["u_b"], c["v_b"]], axis=1)
        return pts_a, pts_b

    @property
    def error_px(self) -> float:
        """Error against ground truth (see the module docstring); NaN without F or GT."""
        F = self.F
        if F is None or self.F_gt is None:
            return float("nan")
        return gt_error_px(F, self.F_gt, *self.pts())


def read_results(
    bag: str | Path, namespace: str = OUTPUT_NAMESPACE, gt_bag: str | Path | None = None
) -> list[FrameResult]:
    """Per-pair answers found in ``bag`` (by run, then stamp), with GT from ``gt_bag`` or ``bag``.

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
            if msg.topic == topics["estimate"]:
                m = deserialize_message(msg.data, TwoViewEstimate)
                frame(msg.topic, stamp_ns(m.header.stamp)).estimate = m
            else:
                m = deserialize_message(msg.data, MatchArray)
                frame(msg.topic, stamp_ns(m.header.stamp)).match_rows = match_table(m)
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
