"""A bag through the session into a bag of the node's outputs (``sepfm_ros process``).

Every result is flushed to the output as soon as it is computed
(:class:`~sepfm_ros.ros.bags.writer.BagWriter`), so an interruption leaves a readable output.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from rclpy.serialization import serialize_message
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability
from rosbags.interfaces import QosTime as _QosTime
from tqdm import tqdm

from sepfm_msgs.msg import TwoViewEstimate
from sepfm_ros.pipeline.pipeline import Pipeline
from sepfm_ros.ros.bags.errors import BagError
from sepfm_ros.ros.bags.inputs import (
    detect_inputs,
)
from sepfm_ros.ros.bags.pairing import (
    PairJob,
    iter_pairs,
    pairing_slop_ns,
    read_camera_infos,
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
    DIAGNOSTIC_STATUS,
    GROUND_TRUTH_TOPIC,
    IMAGE,
    MATCH_ARRAY,
    TRANSFORM_STAMPED,
    TWO_VIEW_ESTIMATE,
    format_stamp,
)
from sepfm_ros.ros.bags.writer import BagWriter, check_output_path
from sepfm_ros.ros.msgs.headers import stamp_ns
from sepfm_ros.ros.node.signals import DeferredStop
from sepfm_ros.ros.session.answer import (
    ESTIMATOR_INPUT,
    AnswerSettings,
    PairCalibration,
    answer_pair,
    decode_pair,
    internal_error_text,
)
from sepfm_ros.ros.session.calibrated import CalibratedStream
from sepfm_ros.ros.session.parameters import (
    monitor_config,
    pipeline_config,
)

# The node's publishers: reliable, volatile, keep last 10 (recorded as the offered QoS).
_ZERO = _QosTime(0, 0)


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


def run_process(
    bag: Path,
    out: Path,
    params: dict[str, Any],
    mode: str | None = None,
    progress: bool = True,
    namespace: str = OUTPUT_NAMESPACE,
    on_done: Callable[[int, int, int], None] | None = None,
    left: str | None = None,
    right: str | None = None,
    image: str | None = None,
    slop_given: bool = False,
    stop: DeferredStop | None = None,
) -> tuple[int, int]:
    """Process ``bag`` into a new bag ``out``; returns (pairs processed, pairs expected).

    The input topics are ``left``/``right`` or ``image`` when given, else picked from the bag
    (:func:`~sepfm_ros.ros.bags.inputs.detect_inputs`; the pick is printed on stderr). Stereo
    pairs form within :func:`pairing_slop_ns` (``slop_given``: ``sync_slop_s`` was set by the
    user and is used as is).

    ``on_done(k, total, stamp_ns)`` is called after pair k's results were flushed to ``out``
    (they survive any interruption from then on).

    Raises BagError subclasses on bad input; KeyboardInterrupt propagates after ``out`` is closed
    (readable, holding every result so far). ``stop``: a deferred stop request, checked before
    each pair (see :class:`~sepfm_ros.ros.node.signals.DeferredStop`).
    """
    check_output_path(out)
    topics = output_topics(namespace)
    try:
        config = pipeline_config(params)
    except ValueError as err:
        raise BagError(str(err)) from None
    with BagReader(bag) as reader:
        spec = detect_inputs(reader, mode, left, right, image)
        inputs = validate_inputs(reader, spec)
        if stop is not None:
            stop.check()
        slop_ns = None
        if spec.mode == "stereo":
            slop_ns = pairing_slop_ns(params, inputs.stamps[spec.topics[0]], slop_given)
        for line in inputs.warnings(params["stamp_jump_reset_s"]):
            print(f"sepfm_ros process: {line}", file=sys.stderr, flush=True)
        if spec.picked:
            print(
                f"sepfm_ros process: input {spec.describe()} (picked from the bag's image "
                "topics; choose with --left/--right or --image)",
                file=sys.stderr,
                flush=True,
            )
        total = inputs.pair_count(spec, params, slop_ns)
        if total == 0:
            gap, flag = int(params["frame_gap"]), "-p sync_slop_s:=SECONDS"
            raise BagError(inputs.no_pairs_reason(spec, gap, slop_ns, flag))
        has_gt = GROUND_TRUTH_TOPIC in reader.topics
        if has_gt:
            reader.require(GROUND_TRUTH_TOPIC, (IMAGE,))
        pipeline = Pipeline(config, cache_size=8)
        infos = read_camera_infos(reader, spec) if params["use_camera_info"] else None
        calibrated = None
        if infos is not None:
            rectified = params["images"] == "rectified" or (
                params["images"] == "auto" and spec.rectified()
            )
            calibrated = CalibratedStream(
                spec.mode == "stereo", rectified, monitor_config(params), OUTPUT_NAMESPACE[1:]
            )
            print(
                f"sepfm_ros process: camera_info from {' + '.join(infos.topics)}: F in "
                "undistorted pixels of K, relative pose"
                + (" and calibration check" if spec.mode == "stereo" else ""),
                file=sys.stderr,
                flush=True,
            )
        done = 0
        with BagWriter(out, flush_interval_s=None) as writer:
            writer.add_topic(topics["estimate"], TWO_VIEW_ESTIMATE, (OUTPUT_QOS,))
            writer.add_topic(topics["matches"], MATCH_ARRAY, (OUTPUT_QOS,))
            if calibrated is not None:
                topics = {**topics, **calibrated_topics(namespace)}
                writer.add_topic(topics["relative_transform"], TRANSFORM_STAMPED, (OUTPUT_QOS,))
                writer.add_topic(topics["calibration_check"], DIAGNOSTIC_STATUS, (OUTPUT_QOS,))
            if has_gt:
                writer.add_topic(GROUND_TRUTH_TOPIC, IMAGE, reader.topics[GROUND_TRUTH_TOPIC].qos)
                for raw in reader.messages([GROUND_TRUTH_TOPIC]):
                    writer.write(GROUND_TRUTH_TOPIC, raw.log_time_ns, raw.data)
                writer.flush()
            bar = tqdm(
                total=total,
                unit="pair",
                desc=f"process {bag.name}",
                file=sys.stderr,
                disable=not progress,
                dynamic_ncols=True,
            )
            try:
                for job in iter_pairs(reader, spec, params, slop_ns):
                    if stop is not None:
                        stop.check()
                    calib = None
                    if calibrated is not None:
                        calib = PairCalibration(calibrated, infos.at(stamp_ns(job.header.stamp)))
                    for data in process_pair(pipeline, job, params, topics, calib):
                        writer.write(data[0], job.log_time_ns, data[1])
                    writer.flush()  # every result survives a kill from now on
                    done += 1
                    bar.update(1)
                    if on_done is not None:
                        on_done(done, total, stamp_ns(job.header.stamp))
            finally:
                bar.close()
    return done, total


def process_pair(
    pipeline: Pipeline,
    job: PairJob,
    params: dict[str, Any],
    topics: dict[str, str],
    calibration: PairCalibration | None = None,
) -> list[tuple[str, bytes]]:
    """The node's messages for one pair as (topic, CDR bytes), in the order the node publishes
    them (:func:`~sepfm_ros.ros.session.answer.answer_pair`: the same answer as the node's, a
    failure record for a pair that cannot be decoded or whose frame size changed).

    ``calibration``: the stream's calibration and the pair's latest camera_info messages: F in
    undistorted pixels, the pose, plus the relative transform and calibration check topics.
    """
    settings = AnswerSettings.of(pipeline.config, params["publish_unreliable"])
    decoded = decode_pair(job.msg_a, job.msg_b, job.stereo)
    keys = (job.key_a, job.key_b)
    answer = answer_pair(pipeline, job.headers(), decoded, settings, keys, calibration)
    if answer.result is None:
        stamp = format_stamp(stamp_ns(job.header.stamp))
        print(f"\npair at {stamp}: {answer.estimate.status_text}", file=sys.stderr)
        if answer.error is not None:
            print(internal_error_text(answer.error), file=sys.stderr)
    update = answer.cameras_update
    if update is not None and update.error is not None:
        print(f"\ncamera_info unusable: {update.reason}", file=sys.stderr)
    out = []
    if answer.transform is not None:
        out.append((topics["relative_transform"], serialize_message(answer.transform)))
    if answer.calibration is not None:
        out.append((topics["calibration_check"], serialize_message(answer.calibration)))
    out.append((topics["matches"], serialize_message(answer.matches)))
    out.append((topics["estimate"], serialize_message(answer.estimate)))
    return out
