"""The fleet audit's bag side: what a bag holds (:func:`inspect_bag`) and one time slice's pairs
through the node's answer path (:func:`audit_slice`). Both run on the engine's workers and
return plain data (:mod:`sepfm_ros.fleet.records`), or a :class:`TaskFailure` saying why the bag
cannot be audited: a bad bag is a row with its reason, never a crashed run.

Each pair is answered by the bag's session, as the node answers it
(:class:`~sepfm_ros.ros.offline.stream.BagStream`, with the calibration check's sliding window
when the bag has calibrated stereo), and :func:`pair_record` reads the audit's figures from that
typed answer: the audit's judgement is the node's, not a copy of it.
"""

from __future__ import annotations

import math
import traceback
from collections import deque
from collections.abc import Iterator
from typing import Any

import numpy as np

from sepfm_ros.fleet.records import (
    FLAG_LEVELS,
    BagInfo,
    CameraIdentity,
    InputChoice,
    PairRecord,
    SliceResult,
    SliceTask,
    TaskFailure,
)
from sepfm_ros.fleet.slices import warm_pairs
from sepfm_ros.ros.bags.errors import BagError
from sepfm_ros.ros.bags.inputs import InputSpec, detect_inputs
from sepfm_ros.ros.bags.pairing import (
    PairJob,
    expected_pairs,
)
from sepfm_ros.ros.bags.reader import BagReader, RawMessage
from sepfm_ros.ros.bags.types import CAMERA_INFO, header_stamp_ns
from sepfm_ros.ros.msgs.diagnostics import status_values
from sepfm_ros.ros.msgs.headers import stamp_ns
from sepfm_ros.ros.offline.stream import BagStream, stereo_slop_ns
from sepfm_ros.ros.session.answer import (
    PairAnswer,
)

# header stamps of the first camera read to find its frame period and the stereo slop
PERIOD_SAMPLE = 201
LEVELS = {0: "OK", 1: "WARN", 2: "ERROR", 3: "STALE"}


def _failure(bag: str, err: BaseException) -> TaskFailure:
    if isinstance(err, BagError):
        return TaskFailure(str(err))
    where = traceback.extract_tb(err.__traceback__)[-1]
    return TaskFailure(
        f"internal error reading {bag}: {type(err).__name__}: {err} "
        f"({where.filename}:{where.lineno})"
    )


def _slice_spec(reader: BagReader, info: BagInfo) -> InputSpec:
    """The inputs :func:`inspect_bag` chose for the bag."""
    if info.mode == "stereo":
        return detect_inputs(reader, "stereo", info.topics[0], info.topics[1])
    return detect_inputs(reader, "motion", image=info.topics[0])


def _no_pairs(spec: InputSpec, frames: tuple[int, ...], frame_gap: int) -> TaskFailure:
    have = ", ".join(f"{t} has {n} frame(s)" for t, n in zip(spec.topics, frames, strict=True))
    need = (
        "a frame on each camera"
        if spec.mode == "stereo"
        else f"more than frame_gap ({frame_gap}) frames"
    )
    return TaskFailure(f"no pairs: {have}; {spec.mode} needs {need}")


def _camera(reader: BagReader, topic: str, info_topic: str) -> CameraIdentity:
    """What the bag says about one camera: its first camera_info, else its first image."""
    if info_topic in reader.topics and reader.topics[info_topic].msgtype == CAMERA_INFO:
        for raw in reader.messages([info_topic]):
            m = reader.deserialize(raw)
            return CameraIdentity(
                topic,
                str(m.header.frame_id),
                (int(m.width), int(m.height)),
                tuple(float(v) for v in np.ravel(m.k)),
                tuple(float(v) for v in np.ravel(m.d)),
                tuple(float(v) for v in np.ravel(m.p)),
            )
    for raw in reader.messages([topic]):
        m = reader.deserialize(raw)
        size = (int(getattr(m, "width", 0)), int(getattr(m, "height", 0)))
        return CameraIdentity(topic, str(m.header.frame_id), size)
    return CameraIdentity(topic, "", (0, 0))


def _first_stamps(reader: BagReader, topic: str) -> list[int]:
    stamps = []
    for raw in reader.messages([topic]):
        stamps.append(header_stamp_ns(raw.data))
        if len(stamps) >= PERIOD_SAMPLE:
            break
    return stamps


def inspect_bag(bag: str, params: dict[str, Any], choice: InputChoice) -> Any:
    """The bag's :class:`BagInfo` (inputs, rig identity, span, pairing slop), or a
    :class:`TaskFailure` when it cannot be audited (missing, corrupt, no input images, no
    pairs)."""
    try:
        with BagReader(bag) as reader:
            spec = detect_inputs(reader, choice.mode, choice.left, choice.right, choice.image)
            frames = tuple(reader.topics[t].count for t in spec.topics)
            expected = expected_pairs(reader, spec, params)
            if expected == 0:
                return _no_pairs(spec, frames, int(params["frame_gap"]))
            stamps = _first_stamps(reader, spec.topics[0])
            steps = sorted(b - a for a, b in zip(stamps, stamps[1:], strict=False) if b > a)
            period = steps[len(steps) // 2] if steps else 100_000_000
            slop = stereo_slop_ns(spec, params, stamps, choice.slop_given)
            infos = spec.camera_info_topics()
            cameras = tuple(_camera(reader, t, i) for t, i in zip(spec.topics, infos, strict=True))
            calibrated = (
                spec.mode == "stereo"
                and bool(params["use_camera_info"])
                and all(t in reader.topics and reader.topics[t].count for t in infos)
            )
            return BagInfo(
                str(bag), spec.mode, tuple(spec.topics), calibrated, cameras,
                reader.start_time_ns, reader.end_time_ns, int(period), slop, expected, frames,
            )  # fmt: skip
    except Exception as err:  # noqa: BLE001 - every failure becomes the bag's row
        return _failure(bag, err)


class _From:
    """A bag reader whose messages start at a log time (what a slice reads)."""

    def __init__(self, reader: BagReader, start_ns: int) -> None:
        self.reader, self.start_ns = reader, start_ns

    def messages(self, topics: Any) -> Iterator[RawMessage]:
        start = self.start_ns if self.start_ns > self.reader.start_time_ns else None
        return self.reader.messages(topics, start)


def _correction(answer: PairAnswer, level: str) -> dict[str, Any]:
    """The correction fields of a pair's record: the rig's correction after the pair, or why a
    flagged pair has none."""
    result = answer.calibrated.correction if answer.calibrated is not None else None
    if result is None:
        return {}
    fix = result.correction
    if fix is None:
        return {"correction_reason": result.reason if level in FLAG_LEVELS else ""}
    axes, half = (tuple(float(v) for v in a) for a in (fix.axes_deg, fix.interval_deg))
    return {
        "correction_pitch_deg": axes[0],
        "correction_yaw_deg": axes[1],
        "correction_roll_deg": axes[2],
        "correction_pitch_ci95_deg": half[0],
        "correction_yaw_ci95_deg": half[1],
        "correction_roll_ci95_deg": half[2],
        "correction_yaw_determined": bool(fix.yaw_determined),
        "correction_pairs": int(fix.n_pairs),
    }


def pair_record(job: PairJob, answer: PairAnswer) -> PairRecord:
    """The audit's figures of one pair, read from the node's answer for it."""
    est = answer.estimate
    check = answer.calibrated.check if answer.calibrated is not None else None
    rotation = epipolar = math.nan
    if check is not None and check.usable:
        rotation, epipolar = check.rotation_error_deg, check.epipolar_median_px
    level, window_rot, window_x = "", math.nan, math.nan
    if answer.calibration is not None:
        level = LEVELS.get(int.from_bytes(answer.calibration.level, "little"), "ERROR")
        values = status_values(answer.calibration)
        window_rot = float(values.get("rotation_error_deg", "nan"))
        window_x = float(values.get("rotation_x_deg", "nan"))
    return PairRecord(
        stamp_ns(job.header.stamp),
        job.log_time_ns,
        est.status_text,
        answer.has_f,
        int(est.matches),
        int(est.inliers),
        float(est.inlier_error_px) if answer.has_f else math.nan,
        float(rotation),
        float(epipolar),
        window_rot,
        window_x,
        level,
        **_correction(answer, level),
    )


def audit_slice(task: SliceTask) -> Any:
    """The pairs of one slice (:class:`SliceResult`), or a :class:`TaskFailure`.

    THE adapter between the audit and the answer path: everything the audit knows of a pair
    comes from here.
    """
    info, params = task.info, task.params
    try:
        with BagReader(info.bag) as reader:
            spec = _slice_spec(reader, info)
            stream = BagStream.open(reader, spec, params, info.slop_ns)
            stream.reader = _From(reader, task.read_from_ns)
            before: deque[PairJob] = deque(maxlen=warm_pairs(params))
            pairs: list[PairRecord] = []
            warm = 0
            for job in stream.pairs():
                if job.log_time_ns < task.t0_ns:
                    before.append(job)  # only the last window's pairs are answered
                    continue
                if job.log_time_ns >= task.t1_ns:
                    break
                while before:
                    stream.answer(before.popleft())
                    warm += 1
                pairs.append(pair_record(job, stream.answer(job)))
            return SliceResult(task.index, pairs, warm)
    except Exception as err:  # noqa: BLE001 - every failure becomes the bag's row
        return _failure(info.bag, err)
