"""``sepfm_ros process BAG -o OUT``: the node's pipeline over a bag, without DDS.

BAG is a rosbag2 bag (sqlite3 or mcap) or a ROS 1 ``.bag`` file. The input images are the topics
given with ``--left TOPIC --right TOPIC`` (stereo) or ``--image TOPIC`` (motion), Image or
CompressedImage; without them they are picked from the bag (one camera: motion; two whose names
differ by left/right: stereo; the pick is printed) or, when the bag holds several cameras, an
error lists its image topics. The images are paired as the node does (its approximate-time
policy for stereo, frame t - ``frame_gap`` and t for motion), except that stereo pairs form
within half the left frame period unless ``-p sync_slop_s:=...`` is given, so a right camera that
lags by 10-20 ms still pairs. Irregular header stamps are handled as the node handles them, with
a warning per topic: a frame whose stamp repeats or steps back is skipped, and a jump back of
more than ``stamp_jump_reset_s`` (a looped bag, a restarted driver) restarts the pairing there.
The command runs the node's
:class:`~sepfm_ros.pipeline.pipeline.Pipeline` with the same parameters (``-p name:=value``,
the node's parameter names, e.g. ``-p seed:=0 -p method:=sep5``) and writes
the node's outputs with the source stamps to OUT: ``/sepfm/estimate`` (sepfm_msgs/TwoViewEstimate,
one per pair, a failure record for a pair that cannot be used), ``/sepfm/matches``
(sepfm_msgs/MatchArray), with camera_info ``/sepfm/relative_transform`` and
``/sepfm/calibration_check`` (plus a copy of ``/ground_truth/fundamental`` when BAG has it),
logged at the log time of the input message that completed each pair, so OUT plays in step
with BAG. The answers are the node's (:mod:`sepfm_ros.ros.answer`).

A progress bar runs on stderr (``--print-done`` also prints a line ``done K/N STAMP`` on stdout for
each pair once its results are safely in OUT, for programs that watch the progress); at the end a
summary (per-frame table with ``--table``) is printed,
scored against the ground truth when the bag has it. Every result is flushed to OUT as soon as it
is computed (see :class:`~sepfm_ros.ros.bags.writer.BagWriter`), so Ctrl-C, SIGTERM or even SIGKILL
leave a readable OUT holding every result computed before the interruption.

Exit codes: 0 done, 1 bad input (message on stderr, no traceback: an unreadable bag, no pair to
form, an output name of another format, no pair whose images decode), 130 interrupted.
"""

from __future__ import annotations

import argparse
import bisect
import sys
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

from rclpy.serialization import deserialize_message, serialize_message
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability
from rosbags.interfaces import QosTime as _QosTime
from sensor_msgs.msg import CameraInfo, CompressedImage, Image
from tqdm import tqdm

from sepfm_msgs.msg import TwoViewEstimate
from sepfm_ros.pipeline.pipeline import Pipeline
from sepfm_ros.ros.answer import (
    ESTIMATOR_INPUT,
    AnswerSettings,
    BadInput,
    PairCalibration,
    PairHeaders,
    answer_pair,
    decode_pair,
    precheck,
)
from sepfm_ros.ros.bags.errors import BagCorruptError, BagError
from sepfm_ros.ros.bags.inputs import (
    InputSpec,
    camera_info_topics,
    detect_inputs,
    no_pairs_reason,
)
from sepfm_ros.ros.bags.reader import BagReader
from sepfm_ros.ros.bags.types import (
    CAMERA_INFO,
    DIAGNOSTIC_STATUS,
    GROUND_TRUTH_TOPIC,
    IMAGE,
    MATCH_ARRAY,
    TRANSFORM_STAMPED,
    TWO_VIEW_ESTIMATE,
    format_stamp,
    header_stamp_ns,
)
from sepfm_ros.ros.bags.writer import BagWriter, check_output_path
from sepfm_ros.ros.calibrated import CalibratedStream
from sepfm_ros.ros.image_conversion import ZeroStepNotes
from sepfm_ros.ros.keep_serving import internal_error_text
from sepfm_ros.ros.messages import copy_header, stamp_ns
from sepfm_ros.ros.parameters import PARAMS, monitor_config, parameter_error, pipeline_config
from sepfm_ros.ros.results import (
    OUTPUT_NAMESPACE,
    FrameResult,
    calibrated_topics,
    format_summary,
    format_table,
    output_topics,
    read_results,
    summarize,
)
from sepfm_ros.ros.signals import DeferredStop, install_stop_handlers, restore_handlers
from sepfm_ros.stream.pairing import Frame, MotionPairing, StereoPairing, stamp_order_effects
from sepfm_ros.stream.sync import LEFT, RIGHT

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


@dataclass
class PairJob:
    """One pair, as the node's worker gets it (a = left/earlier, b = right/current).

    ``log_time_ns``: the bag's log time of the message that completed the pair; ``run``: how
    many times the pairing restarted before it (the input's stamps jumped back); ``stereo``:
    two cameras (whose image sizes may differ), else one camera's frames.
    """

    msg_a: Any
    msg_b: Any
    header: Any
    key_a: Any
    key_b: Any
    log_time_ns: int = 0
    run: int = 0
    stereo: bool = False

    def headers(self) -> PairHeaders:
        """The pair's output header and its images' headers."""
        return PairHeaders(self.header, self.msg_a.header, self.msg_b.header)


@dataclass
class InputStamps:
    """The input topics' header stamps: (topic, stamp ns) in bag order."""

    topics: tuple[str, ...]
    sequence: list[tuple[str, int]]
    skipped: list[tuple[str, int, BadInput]] = field(default_factory=list)

    @cached_property
    def stamps(self) -> dict[str, list[int]]:
        """Each topic's stamps (ns), in bag order."""
        out: dict[str, list[int]] = {t: [] for t in self.topics}
        for topic, stamp in self.sequence:
            out[topic].append(stamp)
        return out

    @property
    def counts(self) -> dict[str, int]:
        """Each topic's number of usable frames (not skipped for their fields)."""
        return {t: len(v) for t, v in self.stamps.items()}

    @property
    def skipped_counts(self) -> dict[str, int]:
        """Each topic's number of frames skipped for unusable fields."""
        return {t: sum(s[0] == t for s in self.skipped) for t in self.topics}

    def no_pairs_reason(
        self, spec: InputSpec, frame_gap: int, slop_ns: int | None, slop_flag: str | None
    ) -> str:
        """Why these stamps give no pair (:func:`~sepfm_ros.ros.bags.inputs.no_pairs_reason`)."""
        return no_pairs_reason(
            spec, self.counts, frame_gap, slop_ns, slop_flag, self.skipped_counts
        )

    def warnings(self, jump_back_s: float) -> list[str]:
        """One line per topic whose stamps repeat, step back or jump back, saying what the
        pairing (the node's) does with them."""
        lines = []
        for topic in self.topics:
            bad = [b for t, _, b in self.skipped if t == topic]
            if bad:
                lines.append(
                    f"warning: {topic}: {len(bad)} message(s) with unusable fields are skipped, "
                    f"as the node skips them (first: {bad[0].kind}: {bad[0].text})"
                )
        for topic, stamps in self.stamps.items():
            skipped, restarts = stamp_order_effects(stamps, jump_back_s)
            if skipped or restarts:
                lines.append(
                    f"warning: {topic}: {skipped} frame(s) whose header stamp is not after the "
                    f"newest are skipped and {restarts} jump(s) back of over {jump_back_s:g} s "
                    "(a looped bag, a restarted driver) restart the pairing, as in the node"
                )
        return lines

    def pair_count(self, spec: InputSpec, params: dict[str, Any], slop_ns: int | None) -> int:
        """How many pairs :func:`iter_pairs` will form (the node's pairing run on the stamps)."""
        events = ((topic, stamp, None, 0) for topic, stamp in self.sequence)
        return sum(1 for _ in paired_frames(spec, params, slop_ns, events))


@dataclass
class Paired:
    """A pair formed by :func:`paired_frames`: its two frames, the pairing's restarts before it
    and the log time (ns) of the input that completed it."""

    a: Frame[Any]
    b: Frame[Any]
    run: int
    log_time_ns: int


def paired_frames(
    spec: InputSpec,
    params: dict[str, Any],
    slop_ns: int | None,
    events: Iterable[tuple[str, int, Any, int]],
) -> Iterator[Paired]:
    """The node's pairing (:mod:`sepfm_ros.stream.pairing`) of input events (topic, stamp ns,
    item, log time ns) in bag order."""
    jump_s = float(params["stamp_jump_reset_s"])
    if spec.mode == "stereo":
        if slop_ns is None:
            slop_ns = int(round(params["sync_slop_s"] * 1e9))
        stereo: StereoPairing[Any] = StereoPairing(slop_ns, int(params["sync_queue_size"]), jump_s)
        for topic, stamp, item, log_time in events:
            side = LEFT if topic == spec.topics[0] else RIGHT
            out = stereo.add(side, Frame(item, stamp))
            if out.pair is not None:
                yield Paired(out.pair[0], out.pair[1], stereo.resets, log_time)
    else:
        motion: MotionPairing[Any] = MotionPairing(int(params["frame_gap"]), jump_s)
        for _, stamp, item, log_time in events:
            out = motion.add(Frame(item, stamp))
            if out.pair is not None:
                yield Paired(out.pair[0], out.pair[1], motion.resets, log_time)


def iter_pairs(
    reader: BagReader, spec: InputSpec, params: dict[str, Any], slop_ns: int | None = None
) -> Iterator[PairJob]:
    """The pairs the node would form from the bag's input messages, in order.

    Pairing is the node's (:mod:`sepfm_ros.stream.pairing`): a frame whose stamp is not after its
    topic's newest is skipped, a jump back of more than ``stamp_jump_reset_s`` restarts the
    pairing. ``slop_ns`` overrides ``sync_slop_s`` (stereo), see :func:`pairing_slop_ns`.
    """
    msg_class = input_class(spec)
    zero_step = ZeroStepNotes()

    def events() -> Iterator[tuple[str, int, Any, int]]:
        for raw in reader.messages(spec.topics):
            msg = deserialize_message(raw.data, msg_class)
            if precheck(msg) is not None:  # as the node, skip unusable fields before pairing
                continue
            if (note := zero_step.note(raw.topic, msg)) is not None:
                print(f"\nsepfm_ros process: warning: {note}", file=sys.stderr, flush=True)
            yield raw.topic, stamp_ns(msg.header.stamp), msg, raw.log_time_ns

    stereo = spec.mode == "stereo"
    for p in paired_frames(spec, params, slop_ns, events()):
        tags = ("l", "r") if stereo else ()
        yield PairJob(
            p.a.item,
            p.b.item,
            copy_header((p.a if stereo else p.b).item.header),  # left / current frame's
            (p.run, *tags[:1], p.a.stamp_ns),
            (p.run, *tags[1:], p.b.stamp_ns),
            p.log_time_ns,
            p.run,
            stereo=stereo,
        )


def input_class(spec: InputSpec) -> type:
    """The message class of the input topics: CompressedImage or Image."""
    return CompressedImage if spec.transport == "compressed" else Image


def validate_inputs(reader: BagReader, spec: InputSpec) -> InputStamps:
    """Scan the input topics' header stamps before any output exists, and check each message's
    fields as the node does before pairing (:func:`~sepfm_ros.ros.answer.precheck`).

    Raises BagCorruptError (unreadable data). Irregular stamps are not refused: the pairing
    skips or restarts on them as the node does, and a message with unusable fields is skipped
    as in the node (:meth:`InputStamps.warnings`).
    """
    msg_class = input_class(spec)
    sequence, skipped = [], []
    for raw in reader.messages(spec.topics):
        stamp = header_stamp_ns(raw.data)
        try:
            msg = deserialize_message(raw.data, msg_class)
        except Exception as err:  # noqa: BLE001 - any CDR the message class cannot read
            raise BagCorruptError(f"{raw.topic}: unreadable message at {stamp} ns: {err}") from None
        bad = precheck(msg)
        if bad is None:
            sequence.append((raw.topic, stamp))
        else:
            skipped.append((raw.topic, stamp, bad))
    return InputStamps(tuple(spec.topics), sequence, skipped)


def pairing_slop_ns(params: dict[str, Any], left_stamps: list[int], slop_given: bool) -> int:
    """The stereo pairing slop (ns) for a bag whose left header stamps are ``left_stamps``.

    ``sync_slop_s`` when the user set it (``slop_given``); otherwise the larger of its default
    and just under half the left stream's median frame period, so that each left frame pairs
    with its nearest right frame even when a cheap rig's right camera lags by 10-20 ms (the
    node's 5 ms default pairs none of them). Half a period can never pair a frame with a
    neighbour's partner.
    """
    slop = int(round(params["sync_slop_s"] * 1e9))
    if slop_given or len(left_stamps) < 2:
        return slop
    steps = sorted(b - a for a, b in zip(left_stamps, left_stamps[1:], strict=False) if b > a)
    if not steps:
        return slop
    return max(slop, steps[len(steps) // 2] // 2 - 1)


@dataclass
class CameraInfos:
    """The bag's camera_info messages of each input camera, by stamp."""

    topics: tuple[str, ...]
    stamps: list[list[int]]
    messages: list[list[Any]]

    def at(self, stamp: int) -> list[Any]:
        """The latest camera_info of each camera at ``stamp`` (ns; the first one before it)."""
        out = []
        for stamps, msgs in zip(self.stamps, self.messages, strict=True):
            k = max(bisect.bisect_right(stamps, stamp) - 1, 0)
            out.append(msgs[k])
        return out


def read_camera_infos(reader: BagReader, spec: InputSpec) -> CameraInfos | None:
    """The camera_info beside each input topic, when the bag has them all (else None)."""
    topics = camera_info_topics(reader, spec)
    if not all(t in reader.topics and reader.topics[t].count for t in topics):
        return None
    for t in topics:
        reader.require(t, (CAMERA_INFO,))
    per_topic: dict[str, list[tuple[int, Any]]] = {t: [] for t in topics}
    for raw in reader.messages(list(topics)):
        msg = deserialize_message(raw.data, CameraInfo)
        per_topic[raw.topic].append((stamp_ns(msg.header.stamp), msg))
    ordered = [sorted(per_topic[t], key=lambda e: e[0]) for t in topics]
    return CameraInfos(
        topics, [[s for s, _ in o] for o in ordered], [[m for _, m in o] for o in ordered]
    )


def expected_pairs(reader: BagReader, spec: InputSpec, params: dict[str, Any]) -> int:
    """How many pairs a regular bag gives, from the message counts alone (what a live node fed
    the bag should answer); ``process`` counts its own with :meth:`InputStamps.pair_count`."""
    counts = [reader.topics[t].count for t in spec.topics]
    if spec.mode == "stereo":
        return min(counts)
    return max(0, counts[0] - int(params["frame_gap"]))


def decoded(result: FrameResult) -> bool:
    """The pair's images were decoded (its result is not the record of images it could not use;
    matches the estimator refused came from decoded images)."""
    est = result.estimate
    return est is not None and (
        est.status != TwoViewEstimate.STATUS_BAD_INPUT or est.bad_input_kind == ESTIMATOR_INPUT
    )


def parse_params(items: list[str]) -> dict[str, Any]:
    """``name:=value`` strings -> node parameter values (defaults for the rest), validated."""
    values = {name: spec.default for name, spec in PARAMS.items()}
    for item in items:
        if ":=" not in item:
            raise BagError(f"parameter {item!r} is not of the form name:=value")
        name, text = item.split(":=", 1)
        if name not in PARAMS:
            raise BagError(f"unknown parameter {name!r}; known: {', '.join(PARAMS)}")
        default = PARAMS[name].default
        try:
            if isinstance(default, bool):
                if text.lower() not in ("true", "false"):
                    raise ValueError
                value: Any = text.lower() == "true"
            elif isinstance(default, int):
                value = int(text)
            elif isinstance(default, float):
                value = float(text)
            else:
                value = text
        except ValueError:
            raise BagError(f"parameter {name}: cannot read {text!r}") from None
        error = parameter_error(name, value)
        if error:
            raise BagError(error)
        values[name] = value
    return values


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
    each pair (see :class:`~sepfm_ros.ros.signals.DeferredStop`).
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
    them (:func:`~sepfm_ros.ros.answer.answer_pair`: the same answer as the node's, a failure
    record for a pair that cannot be decoded or whose frame size changed).

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


def _parse(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        prog="sepfm_ros process",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("bag", type=Path, help="input bag: rosbag2 folder, .mcap, .db3 or ROS 1 .bag")
    p.add_argument("-o", "--output", type=Path, required=True, help="output bag (must not exist)")
    p.add_argument("--mode", choices=("stereo", "motion"), help="default: from the bag's topics")
    add_topic_arguments(p)
    p.add_argument(
        "-p",
        "--param",
        action="append",
        default=[],
        metavar="NAME:=VALUE",
        help="a node parameter (e.g. seed:=0, method:=sep5, features:=orb); repeatable",
    )
    p.add_argument("--table", action="store_true", help="print the per-frame table")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument(
        "--print-done",
        action="store_true",
        help="print 'done K/N SEC.NANOSEC' on stdout when a pair's results are safely written",
    )
    return p.parse_args(argv)


def add_topic_arguments(p: argparse.ArgumentParser) -> None:
    """``--left``/``--right``/``--image``: the input topics (shared by process and eval --bags)."""
    p.add_argument("--left", metavar="TOPIC", help="stereo: left image topic (with --right)")
    p.add_argument("--right", metavar="TOPIC", help="stereo: right image topic (with --left)")
    p.add_argument("--image", metavar="TOPIC", help="motion: the image topic")


def print_done(k: int, total: int, stamp: int) -> None:
    """``--print-done``: one flushed line per pair whose results are in the output bag."""
    print(f"done {k}/{total} {stamp // 1_000_000_000}.{stamp % 1_000_000_000:09d}", flush=True)


def main(argv: list[str]) -> int:
    args = _parse(argv)
    stop = DeferredStop()
    previous = install_stop_handlers(stop)
    interrupted = False
    try:
        params = parse_params(args.param)
        done, total = run_process(
            args.bag,
            args.output,
            params,
            args.mode,
            not args.quiet,
            on_done=print_done if args.print_done else None,
            left=args.left,
            right=args.right,
            image=args.image,
            slop_given=any(p.startswith("sync_slop_s:=") for p in args.param),
            stop=stop,
        )
    except BagError as err:
        print(f"sepfm_ros process: error: {err}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        interrupted = True
        done, total = -1, -1
    finally:
        restore_handlers(previous)
    if interrupted and not args.output.exists():
        print("sepfm_ros process: interrupted before any output", file=sys.stderr)
        return 130
    try:
        results = read_results(args.output)
    except BagError as err:
        print(f"sepfm_ros process: error reading back {args.output}: {err}", file=sys.stderr)
        return 1
    if args.table:
        print(format_table(results))
    undecoded = not interrupted and total > 0 and not any(decoded(r) for r in results)
    expected = None if interrupted else total
    print(format_summary(summarize(results, expected)))
    if interrupted:
        print(
            f"sepfm_ros process: interrupted; {args.output} holds the {len(results)} results "
            "computed before the interruption",
            file=sys.stderr,
        )
        return 130
    print(f"wrote {args.output}: {done} of {total} pairs")
    if undecoded:
        print(
            f"sepfm_ros process: error: none of the {total} pairs could be decoded (the reasons "
            "are above)",
            file=sys.stderr,
        )
        return 1
    return 0
