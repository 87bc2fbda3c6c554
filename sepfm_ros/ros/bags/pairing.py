"""The node's pairing over a bag's messages: which pairs the node would form, in order.

Offline paths (``process``, ``calibration_check``, ``audit``, ``eval --bags``) read a bag's
input messages, skip unusable ones as the node does and pair them with the stream's pairing
(:mod:`sepfm_ros.stream.pairing`); this module also reads the stamps first (to count the pairs
and warn about irregular stamps) and the camera_info beside each input camera.
"""

from __future__ import annotations

import bisect
import sys
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

from rclpy.serialization import deserialize_message
from sensor_msgs.msg import CameraInfo, CompressedImage, Image

from sepfm_ros.ros.bags.errors import BagCorruptError
from sepfm_ros.ros.bags.inputs import (
    InputSpec,
    camera_info_topics,
    no_pairs_reason,
)
from sepfm_ros.ros.bags.reader import BagReader
from sepfm_ros.ros.bags.types import (
    CAMERA_INFO,
    header_stamp_ns,
)
from sepfm_ros.ros.msgs.headers import copy_header, stamp_ns
from sepfm_ros.ros.msgs.image_conversion import ZeroStepNotes
from sepfm_ros.ros.session.answer import (
    BadInput,
    PairHeaders,
    precheck,
)
from sepfm_ros.ros.session.session import Session
from sepfm_ros.stream.pairing import Frame, MotionPairing, StereoPairing, stamp_order_effects
from sepfm_ros.stream.sync import LEFT, RIGHT


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

    def pair_count(self, spec: InputSpec, session: Session, slop_ns: int | None) -> int:
        """How many pairs :func:`iter_pairs` will form (the session's pairing run on the
        stamps)."""
        events = ((topic, stamp, None, 0) for topic, stamp in self.sequence)
        return sum(1 for _ in paired_frames(spec, session.pairing(slop_ns), events))


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
    pairing: StereoPairing[Any] | MotionPairing[Any],
    events: Iterable[tuple[str, int, Any, int]],
) -> Iterator[Paired]:
    """The stream's pairing (a new one from :meth:`~sepfm_ros.ros.session.session.Session.pairing`)
    of input events (topic, stamp ns, item, log time ns) in bag order."""
    for topic, stamp, item, log_time in events:
        if isinstance(pairing, StereoPairing):
            out = pairing.add(LEFT if topic == spec.topics[0] else RIGHT, Frame(item, stamp))
        else:
            out = pairing.add(Frame(item, stamp))
        if out.pair is not None:
            yield Paired(out.pair[0], out.pair[1], pairing.resets, log_time)


def warn_on_stderr(text: str) -> None:
    """A warning on stderr, on a line of its own (past a progress bar)."""
    print(f"\nwarning: {text}", file=sys.stderr, flush=True)


def iter_pairs(
    reader: BagReader,
    spec: InputSpec,
    session: Session,
    slop_ns: int | None = None,
    warn: Callable[[str], None] = warn_on_stderr,
) -> Iterator[PairJob]:
    """The pairs the node would form from the bag's input messages, in order.

    Pairing is the session's (:meth:`~sepfm_ros.ros.session.session.Session.pairing`): a frame
    whose stamp is not after its topic's newest is skipped, a jump back of more than
    ``stamp_jump_reset_s`` restarts the pairing. ``slop_ns`` overrides ``sync_slop_s`` (stereo),
    see :func:`pairing_slop_ns`. ``warn``: told once per topic of images read as packed rows
    (step 0), as the node logs it.
    """
    msg_class = input_class(spec)
    zero_step = ZeroStepNotes()

    def events() -> Iterator[tuple[str, int, Any, int]]:
        for raw in reader.messages(spec.topics):
            msg = deserialize_message(raw.data, msg_class)
            if precheck(msg) is not None:  # as the node, skip unusable fields before pairing
                continue
            if (note := zero_step.note(raw.topic, msg)) is not None:
                warn(note)
            yield raw.topic, stamp_ns(msg.header.stamp), msg, raw.log_time_ns

    stereo = spec.mode == "stereo"
    for p in paired_frames(spec, session.pairing(slop_ns), events()):
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
    fields as the node does before pairing (:func:`~sepfm_ros.ros.session.answer.precheck`).

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


def read_camera_infos(
    reader: BagReader, spec: InputSpec, topics: Sequence[str | None] = ()
) -> CameraInfos | None:
    """The camera_info of each input camera, when the bag has them all (else None): the topics
    given in ``topics`` (one per camera, None: the default), else the one beside each input
    topic."""
    beside = camera_info_topics(reader, spec)
    given = list(topics) + [None] * (len(beside) - len(topics))
    topics = tuple(beside[k] if t is None else reader.resolve(t) for k, t in enumerate(given))
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
