"""Is a stereo rig still calibrated? A bag's pairs through the session and the calibration
check's sliding window, with the per-pair figures as CSV and a plot (``calibration_check``'s
library). :func:`check_bag` also returns the correction after the last pair and the camera_info
models of the corrected rig (:mod:`sepfm_ros.ros.offline.corrected_files` writes them)."""

from __future__ import annotations

import csv
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from sepfm_ros.geometry.calibrated.calibration_check import (
    CalibrationStatus,
    MonitorConfig,
    PairCheck,
)
from sepfm_ros.geometry.calibrated.camera import CalibrationError, CameraModel
from sepfm_ros.geometry.calibrated.correction import CorrectionResult
from sepfm_ros.ros.bags.errors import BagError
from sepfm_ros.ros.bags.inputs import detect_inputs
from sepfm_ros.ros.bags.pairing import (
    PairJob,
    validate_inputs,
)
from sepfm_ros.ros.bags.reader import BagReader
from sepfm_ros.ros.bags.types import CAMERA_INFO, format_stamp
from sepfm_ros.ros.msgs.headers import camera_info_topic, stamp_ns
from sepfm_ros.ros.offline.stream import BagStream, stereo_slop_ns


@dataclass
class PairRow:
    """One checked pair: its stamp, figures and the monitor's decision after it, the pair's
    answer (``F``: 3x3 in the answer's coordinates, None without F; ``inliers``) and the rig's
    correction after it (None: the session gave none)."""

    index: int
    stamp_ns: int
    check: PairCheck
    status: CalibrationStatus
    F: np.ndarray | None = None
    inliers: int = 0
    correction: CorrectionResult | None = None


@dataclass
class CheckRun:
    """A checked bag: its pairs and what the check ends with.

    Attributes:
        rows: the checked pairs, in order.
        topics: (left, right) image topics; info_topics: their camera_info topics.
        frames: (left, right) frame ids of the last camera_info (the cameras' names).
        rectified: the images are rectified (``image_rect``).
        correction: the correction after the last pair (None: no pair was checked).
        corrected: camera_info models (left, right) of the corrected rig, None without a
            correction (:meth:`~sepfm_ros.pipeline.calibration.StreamCalibration.corrected_models`).
    """

    rows: list[PairRow]
    topics: tuple[str, str]
    info_topics: tuple[str, str]
    frames: tuple[str, str] = ("", "")
    rectified: bool = False
    correction: CorrectionResult | None = None
    corrected: tuple[CameraModel, CameraModel] | None = None


@dataclass(frozen=True)
class CheckRequest:
    """What to check: the bag, its stereo topics (None: picked from the bag), the camera_info
    topics (None: beside each image topic), the node's parameter values (``slop_given``: the user
    set ``sync_slop_s``, else pairs form within half a frame period) and at most how many pairs
    (0: all)."""

    bag: str
    values: dict[str, Any]
    left: str | None = None
    right: str | None = None
    left_info: str | None = None
    right_info: str | None = None
    slop_given: bool = False
    max_pairs: int = 0


def _missing_info(reader: BagReader, bag: str, topics: tuple[str, str]) -> CalibrationError | None:
    """Why the bag cannot be checked with camera_info ``topics`` (None when both have messages)."""
    for topic in topics:
        if topic not in reader.topics or not reader.topics[topic].count:
            have = ", ".join(
                t for t, i in sorted(reader.topics.items()) if i.msgtype == CAMERA_INFO
            )
            return CalibrationError(
                f"bag {bag} has no camera_info on {topic}: a calibration check needs both cameras'"
                f" camera_info (camera_info topics in the bag: {have or 'none'}; choose them with"
                " --left-info/--right-info)"
            )
        reader.require(topic, (CAMERA_INFO,))
    return None


def _open(
    reader: BagReader, req: CheckRequest, out: TextIO
) -> tuple[BagStream, int, tuple[str, str]]:
    """The bag's stereo stream with its camera_info, how many pairs to check and the
    camera_info topics."""
    spec = detect_inputs(reader, "stereo", req.left, req.right)
    left, right = spec.topics
    infos = (
        reader.resolve(req.left_info or camera_info_topic(left)),
        reader.resolve(req.right_info or camera_info_topic(right)),
    )
    if (missing := _missing_info(reader, req.bag, infos)) is not None:
        raise missing
    inputs = validate_inputs(reader, spec)
    slop_ns = stereo_slop_ns(spec, req.values, inputs.stamps[left], req.slop_given)
    stream = BagStream.open(reader, spec, {**req.values, "use_camera_info": True}, slop_ns, infos)
    stream.warn = lambda text: print(f"warning: {text}", file=out)
    total = stream.pair_count(inputs)  # the node's pairing, run on the stamps
    if total == 0:
        raise BagError(inputs.no_pairs_reason(spec, 0, slop_ns, "-p sync_slop_s:=SECONDS"))
    if req.max_pairs:
        total = min(total, req.max_pairs)
    print(
        f"checking {total} stereo pairs of {req.bag} ({left} + {right}"
        + (", picked from the bag's image topics" if spec.picked else "")
        + f"; {'rectified' if stream.session.rectified else 'raw'} images, pairs within "
        f"{(slop_ns or 0) / 1e6:.1f} ms, calibration from {infos[0]} and {infos[1]})",
        file=out,
    )
    for line in inputs.warnings(req.values["stamp_jump_reset_s"]):
        print(line, file=out)
    return stream, total, infos


def check_bag(
    req: CheckRequest, out: TextIO = sys.stdout, stop: Callable[[], None] | None = None
) -> CheckRun:
    """Check every stereo pair of the bag through the session (the node's answer, its
    calibration monitor and correction); print progress and figures. Raises BagError,
    CalibrationError or ParameterError on bad input; ``stop`` is called before each pair (it
    raises KeyboardInterrupt when a stop was requested)."""
    rows: list[PairRow] = []
    with BagReader(req.bag) as reader:
        stream, total, infos = _open(reader, req, out)
        for job in stream.pairs():
            if stop is not None:
                stop()
            row = _check_one(stream, job, len(rows), out)
            if row is not None:
                rows.append(row)
                print(_row_line(row, total), file=out, flush=True)
            if len(rows) >= total:
                break
        run = CheckRun(rows, stream.spec.topics, infos, rectified=stream.session.rectified)
        if rows:
            run.frames = _frames(stream, rows[-1].stamp_ns)
            run.correction = rows[-1].correction
            run.corrected = stream.session.calibrated.calibration.corrected_models()
    return run


def run_check(
    req: CheckRequest, out: TextIO = sys.stdout, stop: Callable[[], None] | None = None
) -> list[PairRow]:
    """The checked pairs of :func:`check_bag`."""
    return check_bag(req, out, stop).rows


def _frames(stream: BagStream, stamp: int) -> tuple[str, str]:
    """Frame ids of the camera_info in use at ``stamp`` (ns), left and right."""
    if stream.infos is None:
        return ("", "")
    left, right = stream.infos.at(stamp)[:2]
    return (str(left.header.frame_id), str(right.header.frame_id))


def _check_one(stream: BagStream, job: PairJob, index: int, out: TextIO) -> PairRow | None:
    """Check one stereo pair through the node's answer (:meth:`BagStream.answer`); None (with a
    printed reason) when the pair's answer is a failure record (its images cannot be decoded).

    Raises:
        CalibrationError: the camera_info cannot calibrate these images or gives no rig.
    """
    stamp = stamp_ns(job.header.stamp)
    answer = stream.answer(job)
    if answer.result is None:
        print(f"pair at {format_stamp(stamp)}: skipped, {answer.estimate.status_text}", file=out)
        return None
    update = answer.cameras_update
    if update is not None and update.error is not None:
        raise CalibrationError(update.reason)
    calibrated = answer.calibrated
    if calibrated is None or calibrated.check is None or calibrated.status is None:
        problem = stream.session.calibrated.calibration.rig_problem
        raise CalibrationError(problem or "no calibrated stereo rig")
    F = np.reshape(answer.estimate.f, (3, 3)) if answer.has_f else None
    return PairRow(
        index,
        stamp,
        calibrated.check,
        calibrated.status,
        F,
        int(answer.estimate.inliers),
        calibrated.correction,
    )


def _row_line(row: PairRow, total: int) -> str:
    c = row.check
    figures = (
        f"inliers {c.n_inliers:4d}  epipolar median {c.epipolar_median_px:5.2f} px  "
        f"p90 {c.epipolar_p90_px:5.2f} px  rotation {c.rotation_error_deg:6.3f} deg"
        if c.usable
        else f"inliers {c.n_inliers:4d}  (too few to measure)"
    )
    fix = row.correction.correction if row.correction is not None else None
    corrected = (
        ""
        if fix is None
        else f"  corrected pitch {fix.axes_deg[0]:+.3f} roll {fix.axes_deg[2]:+.3f} deg"
        f" ({fix.n_pairs} pairs)"
    )
    return (
        f"[{row.index + 1}/{total}] {format_stamp(row.stamp_ns)}  {figures}  "
        f"-> {row.status.level_name}{corrected}"
    )


#: per-pair CSV columns of the running correction (empty without one)
CORRECTION_COLUMNS = [
    "correction_pitch_deg",
    "correction_yaw_deg",
    "correction_roll_deg",
    "correction_pitch_ci95_deg",
    "correction_yaw_ci95_deg",
    "correction_roll_ci95_deg",
    "correction_pairs",
]


def _correction_cells(result: CorrectionResult | None) -> list[Any]:
    fix = result.correction if result is not None else None
    if fix is None:
        return [""] * len(CORRECTION_COLUMNS)
    return [*fix.axes_deg.tolist(), *fix.interval_deg.tolist(), fix.n_pairs]


def write_csv(rows: list[PairRow], path: Path) -> None:
    """One line per pair: figures, the decision after it and the correction after it
    (degrees about camera b's x, y, z axes, 95 % half-widths, pairs used; empty without
    one)."""
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(
            [
                "pair",
                "stamp_ns",
                "inliers",
                "epipolar_median_px",
                "epipolar_p90_px",
                "rotation_error_deg",
                "rotation_x_deg",
                "rotation_y_deg",
                "rotation_z_deg",
                "level",
                *CORRECTION_COLUMNS,
            ]
        )
        for r in rows:
            c = r.check
            w.writerow(
                [r.index, r.stamp_ns, c.n_inliers, c.epipolar_median_px, c.epipolar_p90_px]
                + [c.rotation_error_deg, *c.rotation_axes_deg.tolist(), r.status.level_name]
                + _correction_cells(r.correction)
            )


def elapsed_s(stamps: list[int]) -> np.ndarray:
    """(K,) seconds since the first of ``stamps`` (ns), counting a step back (the stamps
    jumped back: a looped bag, a restarted driver) as one median forward step."""
    steps = np.diff(np.asarray(stamps, dtype=np.int64)) / 1e9
    forward = steps[steps > 0]
    steps[steps <= 0] = float(np.median(forward)) if forward.size else 0.0
    return np.concatenate([[0.0], np.cumsum(steps)])


def write_plot(rows: list[PairRow], path: Path, config: MonitorConfig) -> None:
    """PNG of the per-pair epipolar error and rotation over time, thresholds and decisions."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = elapsed_s([r.stamp_ns for r in rows])
    epi = np.array([r.check.epipolar_median_px for r in rows])
    p90 = np.array([r.check.epipolar_p90_px for r in rows])
    rot = np.array([r.check.rotation_error_deg for r in rows])
    colors = {0: "#d8f0d8", 1: "#fbe7b5", 2: "#f6c6c6", 3: "#eeeeee"}
    fig, axes = plt.subplots(2, 1, sharex=True, figsize=(9, 5.5))
    for ax in axes:
        for k, r in enumerate(rows):
            t1 = t[k + 1] if k + 1 < len(t) else t[k] + (t[k] - t[k - 1] if k else 1.0)
            ax.axvspan(t[k], t1, color=colors[r.status.level], lw=0)
    axes[0].plot(t, epi, "o-", ms=3, label="median")
    axes[0].plot(t, p90, ".", ms=3, alpha=0.6, label="90th percentile")
    axes[0].axhline(config.warn_epipolar_px, color="orange", ls="--", lw=1, label="WARN")
    axes[0].axhline(config.error_epipolar_px, color="red", ls="--", lw=1, label="ERROR")
    axes[0].set_ylabel("epipolar error (px)")
    axes[0].legend(fontsize=8, loc="upper left")
    axes[1].plot(t, rot, "o-", ms=3, color="C2")
    axes[1].axhline(config.warn_rotation_deg, color="orange", ls="--", lw=1)
    axes[1].axhline(config.error_rotation_deg, color="red", ls="--", lw=1)
    axes[1].set_ylabel("rotation vs calibration (deg)")
    axes[1].set_xlabel(
        "time (s); background: decision (green OK, yellow WARN, red ERROR, grey STALE)"
    )
    axes[0].set_title(f"stereo calibration check: {rows[-1].status.level_name}")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
