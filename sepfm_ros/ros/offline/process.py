"""A bag through the session into a bag of the node's outputs (``sepfm_ros process``).

Every result is flushed to the output as soon as it is computed
(:class:`~sepfm_ros.ros.bags.writer.BagWriter`), so an interruption leaves a readable output.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rclpy.serialization import serialize_message
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability
from rosbags.interfaces import QosTime as _QosTime
from tqdm import tqdm

from sepfm_msgs.msg import TwoViewEstimate
from sepfm_ros.ros.bags.errors import BagError
from sepfm_ros.ros.bags.inputs import (
    detect_inputs,
)
from sepfm_ros.ros.bags.pairing import (
    PairJob,
    validate_inputs,
)
from sepfm_ros.ros.bags.reader import BagReader
from sepfm_ros.ros.bags.results import (
    OUTPUT_NAMESPACE,
    FrameResult,
    calibrated_topics,
    output_topics,
)
from sepfm_ros.ros.bags.types import (
    DIAGNOSTIC_ARRAY,
    GROUND_TRUTH_TOPIC,
    IMAGE,
    MATCH_ARRAY,
    POSE_WITH_COVARIANCE_STAMPED,
    TRANSFORM_STAMPED,
    TWIST_WITH_COVARIANCE_STAMPED,
    TWO_VIEW_ESTIMATE,
    VECTOR3_STAMPED,
    format_stamp,
)
from sepfm_ros.ros.bags.writer import BagWriter, check_output_path
from sepfm_ros.ros.msgs.headers import stamp_ns
from sepfm_ros.ros.offline.stream import BagStream, stereo_slop_ns
from sepfm_ros.ros.session.answer import (
    ESTIMATOR_INPUT,
)
from sepfm_ros.ros.session.internal_errors import internal_error_text
from sepfm_ros.ros.session.parameters import ParameterError

Stop = Callable[[], None]  # raises KeyboardInterrupt when a stop was requested

# The node's publishers: reliable, volatile, keep last 10 (recorded as the offered QoS).
_INF = _QosTime(2147483647, 4294967295)
OUTPUT_QOS = Qos(
    QosHistory.KEEP_LAST,
    10,
    QosReliability.RELIABLE,
    QosDurability.VOLATILE,
    _INF,
    _INF,
    QosLiveliness.AUTOMATIC,
    _INF,
    False,
)


def decoded(result: FrameResult) -> bool:
    """The pair's images were decoded (its result is not the record of images it could not use;
    matches the estimator refused came from decoded images)."""
    est = result.estimate
    return est is not None and (
        est.status != TwoViewEstimate.STATUS_BAD_INPUT or est.bad_input_kind == ESTIMATOR_INPUT
    )


@dataclass
class ProcessInputs:
    """Which inputs ``process`` reads: the mode and topics (None: picked from the bag) and
    whether the user set ``sync_slop_s`` (else stereo pairs form within half a frame period)."""

    mode: str | None = None
    left: str | None = None
    right: str | None = None
    image: str | None = None
    slop_given: bool = False


def _say(text: str) -> None:
    print(f"sepfm_ros process: {text}", file=sys.stderr, flush=True)


def _warn(text: str) -> None:
    """A warning while pairs are processed (on a line of its own, past the progress bar)."""
    print(f"\nsepfm_ros process: warning: {text}", file=sys.stderr, flush=True)


def open_bag_stream(
    reader: BagReader, params: dict[str, Any], choice: ProcessInputs, stop: Stop | None
) -> tuple[BagStream, int]:
    """The bag's stream as ``process`` reads it, and how many pairs it gives (BagError when
    none; the input pick and irregular stamps are reported on stderr)."""
    spec = detect_inputs(reader, choice.mode, choice.left, choice.right, choice.image)
    inputs = validate_inputs(reader, spec)
    if stop is not None:
        stop()
    slop_ns = stereo_slop_ns(spec, params, inputs.stamps[spec.topics[0]], choice.slop_given)
    for line in inputs.warnings(params["stamp_jump_reset_s"]):
        _say(line)
    if spec.picked:
        _say(
            f"input {spec.describe()} (picked from the bag's image topics; choose with "
            "--left/--right or --image)"
        )
    try:
        stream = BagStream.open(reader, spec, params, slop_ns)
    except ParameterError as err:
        raise BagError(str(err)) from None
    stream.warn = _warn
    total = stream.pair_count(inputs)
    if total == 0:
        gap, flag = int(params["frame_gap"]), "-p sync_slop_s:=SECONDS"
        raise BagError(inputs.no_pairs_reason(spec, gap, slop_ns, flag))
    if stream.infos is not None:
        _say(
            f"camera_info from {' + '.join(stream.infos.topics)}: F in undistorted pixels of K,"
            " relative pose" + (" and calibration check" if spec.mode == "stereo" else "")
        )
    return stream, total


def _output_topics(
    writer: BagWriter, reader: BagReader, stream: BagStream, namespace: str
) -> dict[str, str]:
    """Declare the output topics (and copy the ground truth when the bag has it)."""
    topics = output_topics(namespace)
    writer.add_topic(topics["estimate"], TWO_VIEW_ESTIMATE, (OUTPUT_QOS,))
    writer.add_topic(topics["matches"], MATCH_ARRAY, (OUTPUT_QOS,))
    if stream.infos is not None:
        topics = {**topics, **calibrated_topics(namespace)}
        for kind, msgtype in _pose_types(stream.spec.mode == "stereo"):
            writer.add_topic(topics[kind], msgtype, (OUTPUT_QOS,))
        writer.add_topic(topics["calibration_check"], DIAGNOSTIC_ARRAY, (OUTPUT_QOS,))
    if GROUND_TRUTH_TOPIC in reader.topics:
        reader.require(GROUND_TRUTH_TOPIC, (IMAGE,))
        writer.add_topic(GROUND_TRUTH_TOPIC, IMAGE, reader.topics[GROUND_TRUTH_TOPIC].qos)
        for raw in reader.messages([GROUND_TRUTH_TOPIC]):
            writer.write(GROUND_TRUTH_TOPIC, raw.log_time_ns, raw.data)
        writer.flush()
    return topics


def _pose_types(stereo: bool) -> tuple[tuple[str, str], ...]:
    """(kind, message type) of the pose outputs of a stereo rig or of one moving camera."""
    if stereo:
        return (
            ("relative_transform", TRANSFORM_STAMPED),
            ("relative_pose", POSE_WITH_COVARIANCE_STAMPED),
        )
    return (
        ("angular_velocity", TWIST_WITH_COVARIANCE_STAMPED),
        ("translation_direction", VECTOR3_STAMPED),
    )


def run_process(
    bag: Path,
    out: Path,
    params: dict[str, Any],
    choice: ProcessInputs | None = None,
    progress: bool = True,
    namespace: str = OUTPUT_NAMESPACE,
    on_done: Callable[[int, int, int], None] | None = None,
    stop: Stop | None = None,
) -> tuple[int, int]:
    """Process ``bag`` into a new bag ``out``; returns (pairs processed, pairs expected).

    The inputs are ``choice``'s (default: picked from the bag,
    :func:`~sepfm_ros.ros.bags.inputs.detect_inputs`; the pick is printed on stderr). Stereo
    pairs form within :func:`~sepfm_ros.ros.bags.pairing.pairing_slop_ns`.

    ``on_done(k, total, stamp_ns)`` is called after pair k's results were flushed to ``out``
    (they survive any interruption from then on).

    Raises BagError subclasses on bad input; KeyboardInterrupt propagates after ``out`` is closed
    (readable, holding every result so far). ``stop``: called before each pair; it raises
    KeyboardInterrupt when a stop was requested (``DeferredStop.check``).
    """
    check_output_path(out)
    with BagReader(bag) as reader:
        stream, total = open_bag_stream(reader, params, choice or ProcessInputs(), stop)
        done = 0
        with BagWriter(out, flush_interval_s=None) as writer:
            topics = _output_topics(writer, reader, stream, namespace)
            bar = tqdm(
                total=total,
                unit="pair",
                desc=f"process {bag.name}",
                file=sys.stderr,
                disable=not progress,
                dynamic_ncols=True,
            )
            try:
                for job in stream.pairs():
                    if stop is not None:
                        stop()
                    for topic, data in process_pair(stream, job, topics):
                        writer.write(topic, job.log_time_ns, data)
                    writer.flush()  # every result survives a kill from now on
                    done += 1
                    bar.update(1)
                    if on_done is not None:
                        on_done(done, total, stamp_ns(job.header.stamp))
            finally:
                bar.close()
    return done, total


def process_pair(
    stream: BagStream, job: PairJob, topics: dict[str, str]
) -> list[tuple[str, bytes]]:
    """The node's messages for one pair as (topic, CDR bytes), in the order the node publishes
    them (:meth:`BagStream.answer`: the same answer as the node's, a failure record for a pair
    that cannot be decoded or whose frame size changed); with camera_info, the relative
    pose outputs and calibration check too."""
    answer = stream.answer(job)
    if answer.result is None:
        stamp = format_stamp(stamp_ns(job.header.stamp))
        print(f"\npair at {stamp}: {answer.estimate.status_text}", file=sys.stderr)
        if answer.error is not None:
            print(internal_error_text(answer.error), file=sys.stderr)
    update = answer.cameras_update
    if update is not None and update.error is not None:
        print(f"\ncamera_info unusable: {update.reason}", file=sys.stderr)
    out = []
    poses = {
        "relative_transform": answer.transform,
        "relative_pose": answer.relative_pose,
        "angular_velocity": answer.angular_velocity,
        "translation_direction": answer.translation_direction,
    }
    for kind, msg in poses.items():
        if msg is not None:
            out.append((topics[kind], serialize_message(msg)))
    calibration_check = answer.calibration_check()
    if calibration_check is not None:
        out.append((topics["calibration_check"], serialize_message(calibration_check)))
    out.append((topics["matches"], serialize_message(answer.matches)))
    out.append((topics["estimate"], serialize_message(answer.estimate)))
    return out
