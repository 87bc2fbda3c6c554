"""Is a stereo rig still calibrated? A bag's pairs through the session and the calibration
check's sliding window, with the per-pair figures as CSV and a plot (``calibration_check``'s
library)."""

from __future__ import annotations

import argparse
import csv
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from sepfm_ros.geometry.calibrated.calibration_check import (
    CalibrationStatus,
    MonitorConfig,
    PairCheck,
)
from sepfm_ros.geometry.calibrated.camera import CalibrationError
from sepfm_ros.pipeline.pipeline import Pipeline, PipelineConfig
from sepfm_ros.ros.bags.errors import BagError
from sepfm_ros.ros.bags.inputs import detect_inputs
from sepfm_ros.ros.bags.pairing import (
    paired_frames,
    pairing_slop_ns,
    validate_inputs,
)
from sepfm_ros.ros.bags.reader import BagReader
from sepfm_ros.ros.bags.types import CAMERA_INFO, format_stamp
from sepfm_ros.ros.msgs.headers import camera_info_topic, stamp_ns
from sepfm_ros.ros.msgs.image_conversion import ZeroStepNotes
from sepfm_ros.ros.node.signals import DeferredStop
from sepfm_ros.ros.session.answer import (
    AnswerSettings,
    PairCalibration,
    PairHeaders,
    answer_pair,
    decode_pair,
    precheck,
)
from sepfm_ros.ros.session.calibrated import CalibratedStream
from sepfm_ros.ros.session.parameters import parameter_error, parse_params


@dataclass
class PairRow:
    """One checked pair: its stamp, figures and the monitor's decision after it."""

    index: int
    stamp_ns: int
    check: PairCheck
    status: CalibrationStatus


def _monitor_config(args: argparse.Namespace) -> MonitorConfig:
    return MonitorConfig(
        window=args.window,
        min_pairs=args.min_pairs,
        min_inliers=args.min_inliers,
        warn_epipolar_px=args.warn_epipolar_px,
        error_epipolar_px=args.error_epipolar_px,
        warn_rotation_deg=args.warn_rotation_deg,
        error_rotation_deg=args.error_rotation_deg,
    )


class _Rig:
    """The rig's calibration (the node's :class:`CalibratedStream`, whose monitor decides) and
    the latest camera_info of each side."""

    def __init__(self, rectified: bool, monitor: MonitorConfig) -> None:
        self.stream = CalibratedStream(True, rectified, monitor, "calibration_check")
        self.infos: dict[str, Any] = {}

    def calibration(self) -> PairCalibration:
        """The calibration input of the next pair (both sides' camera_info known)."""
        return PairCalibration(self.stream, [self.infos["left"], self.infos["right"]])


def run_check(
    args: argparse.Namespace, out=sys.stdout, stop: DeferredStop | None = None
) -> list[PairRow]:
    """Check every stereo pair of the bag; print progress and figures. Raises BagError,
    CalibrationError or ValueError on bad input; KeyboardInterrupt when ``stop`` was
    requested (checked before each message)."""
    params = parse_params([])  # the node's pairing parameters, at their defaults
    if args.sync_slop is not None:
        error = parameter_error("sync_slop_s", args.sync_slop)
        if error:
            raise ValueError(f"--sync-slop: {error}")
        params["sync_slop_s"] = args.sync_slop
    pipeline = Pipeline(PipelineConfig())
    rows: list[PairRow] = []
    with BagReader(args.bag) as reader:
        spec = detect_inputs(reader, "stereo", args.left, args.right)
        left, right = spec.topics
        left_info = reader.resolve(args.left_info or camera_info_topic(left))
        right_info = reader.resolve(args.right_info or camera_info_topic(right))
        rectified = args.rectified == "yes" or args.rectified == "auto" and spec.rectified()
        for topic in (left_info, right_info):
            if topic not in reader.topics:
                have = ", ".join(
                    t for t, i in sorted(reader.topics.items()) if i.msgtype == CAMERA_INFO
                )
                raise CalibrationError(
                    f"bag {args.bag} has no camera_info on {topic}: a calibration check needs "
                    f"both cameras' camera_info (camera_info topics in the bag: "
                    f"{have or 'none'}; choose them with --left-info/--right-info)"
                )
            reader.require(topic, (CAMERA_INFO,))
        jump_s = params["stamp_jump_reset_s"]
        inputs = validate_inputs(reader, spec)
        slop_ns = pairing_slop_ns(params, inputs.stamps[left], args.sync_slop is not None)
        total = inputs.pair_count(spec, params, slop_ns)  # the node's pairing, run on the stamps
        if total == 0:
            raise BagError(inputs.no_pairs_reason(spec, 0, slop_ns, "--sync-slop"))
        if args.max_pairs:
            total = min(total, args.max_pairs)
        rig = _Rig(rectified, _monitor_config(args))
        print(
            f"checking {total} stereo pairs of {args.bag} ({left} + {right}"
            + (", picked from the bag's image topics" if spec.picked else "")
            + f"; {'rectified' if rectified else 'raw'} images, pairs within "
            f"{slop_ns / 1e6:.1f} ms, calibration from {left_info} and {right_info})",
            file=out,
        )
        for line in inputs.warnings(jump_s):
            print(line, file=out)
        sides = {left_info: "left", right_info: "right"}
        zero_step = ZeroStepNotes()

        def events() -> Iterator[tuple[str, int, Any, int]]:
            """The image messages in bag order; camera_info messages update the rig."""
            for raw in reader.messages([left, right, left_info, right_info]):
                if stop is not None:
                    stop.check()
                msg = reader.deserialize(raw)
                if raw.topic in sides:
                    rig.infos[sides[raw.topic]] = msg
                elif precheck(msg) is None:  # as the node: unusable fields are never paired
                    if (note := zero_step.note(raw.topic, msg)) is not None:
                        print(f"warning: {note}", file=out)
                    yield raw.topic, stamp_ns(msg.header.stamp), msg, raw.log_time_ns

        def check_ready() -> None:
            """Check the complete pairs once both camera_infos are known."""
            while ready and len(rig.infos) == 2 and len(rows) < total:
                stamp, msg_l, msg_r = ready.pop(0)
                row = _check_one(rig, pipeline, stamp, msg_l, msg_r, len(rows), out)
                if row is not None:
                    rows.append(row)
                    print(_row_line(row, total), file=out, flush=True)

        ready: list[tuple[int, Any, Any]] = []  # complete pairs waiting for both camera_infos
        for pair in paired_frames(spec, params, slop_ns, events()):
            ready.append((pair.a.stamp_ns, pair.a.item, pair.b.item))
            check_ready()
            if len(rows) >= total:
                break
        check_ready()  # a camera_info after the last pair
        if ready and len(rows) < total:
            missing = [s for s in ("left", "right") if s not in rig.infos]
            topics = [left_info if s == "left" else right_info for s in missing]
            raise CalibrationError(f"no camera_info message on {', '.join(topics)} in the bag")
    return rows


def _check_one(
    rig: _Rig,
    pipeline: Pipeline,
    stamp: int,
    msg_l: Any,
    msg_r: Any,
    index: int,
    out,
) -> PairRow | None:
    """Check one stereo pair through the node's answer path
    (:func:`~sepfm_ros.ros.session.answer.answer_pair`); None (with a printed reason) when the
    pair's answer is a failure record (its images cannot be decoded).

    Raises:
        CalibrationError: the camera_info cannot calibrate these images or gives no rig.
    """
    headers = PairHeaders(msg_l.header, msg_l.header, msg_r.header)
    decoded = decode_pair(msg_l, msg_r, stereo=True)
    settings = AnswerSettings.of(pipeline.config, publish_unreliable=True)
    answer = answer_pair(pipeline, headers, decoded, settings, calibration=rig.calibration())
    if answer.result is None:
        print(f"pair at {format_stamp(stamp)}: skipped, {answer.estimate.status_text}", file=out)
        return None
    update = answer.cameras_update
    if update is not None and update.error is not None:
        raise CalibrationError(update.reason)
    calibrated = answer.calibrated
    if calibrated is None or calibrated.check is None or calibrated.status is None:
        raise CalibrationError(rig.stream.calibration.rig_problem or "no calibrated stereo rig")
    return PairRow(index, stamp, calibrated.check, calibrated.status)


def _row_line(row: PairRow, total: int) -> str:
    c = row.check
    figures = (
        f"inliers {c.n_inliers:4d}  epipolar median {c.epipolar_median_px:5.2f} px  "
        f"p90 {c.epipolar_p90_px:5.2f} px  rotation {c.rotation_error_deg:6.3f} deg"
        if c.usable
        else f"inliers {c.n_inliers:4d}  (too few to measure)"
    )
    return (
        f"[{row.index + 1}/{total}] {format_stamp(row.stamp_ns)}  {figures}  "
        f"-> {row.status.level_name}"
    )


def write_csv(rows: list[PairRow], path: Path) -> None:
    """One line per pair: figures and the decision after it."""
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
            ]
        )
        for r in rows:
            c = r.check
            w.writerow(
                [r.index, r.stamp_ns, c.n_inliers, c.epipolar_median_px, c.epipolar_p90_px]
                + [c.rotation_error_deg, *c.rotation_axes_deg.tolist(), r.status.level_name]
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
