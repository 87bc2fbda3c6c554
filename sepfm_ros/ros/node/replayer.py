"""Publish a bag's messages into live topics, paced by their log times (:class:`Replayer`)."""

from __future__ import annotations

import importlib
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosReliability
from tqdm import tqdm

from sepfm_ros.ros.bags.errors import BagError, TopicNotFoundError, UnknownTypeError
from sepfm_ros.ros.bags.inputs import COMPRESSED_SUFFIX, NODE_INPUTS, detect_inputs
from sepfm_ros.ros.bags.reader import BagReader, RawMessage, StampChecker
from sepfm_ros.ros.bags.types import IMAGE, has_header, header_stamp_ns

GAP_FACTOR = 3.0


@dataclass
class StampReport:
    """Header-stamp irregularities of one topic: counts of repeats, steps back and gaps."""

    messages: int = 0
    repeated: int = 0
    backwards: int = 0
    gaps: int = 0
    largest_gap_s: float = 0.0

    @property
    def irregular(self) -> bool:
        return bool(self.repeated or self.backwards or self.gaps)


def stamp_irregularities(stamps: Sequence[int], gap_factor: float = GAP_FACTOR) -> StampReport:
    """Count repeated, backwards and gap intervals in a topic's header stamps (ns, bag order).

    A gap is a forward step longer than ``gap_factor`` times the median forward step.
    """
    report = StampReport(messages=len(stamps))
    steps = [b - a for a, b in zip(stamps, stamps[1:], strict=False)]
    report.repeated = sum(1 for d in steps if d == 0)
    report.backwards = sum(1 for d in steps if d < 0)
    forward = sorted(d for d in steps if d > 0)
    if forward:
        median = forward[len(forward) // 2]
        big = [d for d in forward if d > gap_factor * median]
        report.gaps = len(big)
        report.largest_gap_s = max(big, default=0) / 1e9
    return report


def message_class(msgtype: str) -> Any:
    """The rclpy message class of ``pkg/msg/Name`` (UnknownTypeError when not importable)."""
    parts = msgtype.split("/")
    if len(parts) != 3 or parts[1] != "msg":
        raise UnknownTypeError(f"unsupported message type name {msgtype!r}")
    try:
        module = importlib.import_module(f"{parts[0]}.msg")
        return getattr(module, parts[2])
    except (ImportError, AttributeError):
        raise UnknownTypeError(
            f"message type {msgtype} is not installed in this Python environment"
        ) from None


def qos_from_recorded(profiles: Sequence[Qos]) -> QoSProfile:
    """The rclpy QoS to publish with, from the profiles offered when recording.

    Reliable unless every recorded publisher was best effort; transient local only when every
    one was; depth the largest recorded KEEP_LAST depth (default 10).
    """
    qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    if not profiles:
        return qos
    if all(p.reliability == QosReliability.BEST_EFFORT for p in profiles):
        qos.reliability = ReliabilityPolicy.BEST_EFFORT
    if all(p.durability == QosDurability.TRANSIENT_LOCAL for p in profiles):
        qos.durability = DurabilityPolicy.TRANSIENT_LOCAL
    depths = [p.depth for p in profiles if p.history == QosHistory.KEEP_LAST and p.depth > 0]
    if depths:
        qos.history = HistoryPolicy.KEEP_LAST
        qos.depth = max(depths)
    return qos


def parse_remaps(items: Sequence[str]) -> dict[str, str]:
    """``FROM:=TO`` strings -> {from: to} (topic names made absolute)."""
    out = {}
    for item in items:
        if ":=" not in item:
            raise BagError(f"remap {item!r} is not of the form FROM:=TO")
        src, dst = item.split(":=", 1)
        out[absolute_topic(src)] = absolute_topic(dst)
    return out


def absolute_topic(topic: str) -> str:
    return topic if topic.startswith("/") else "/" + topic


class Replayer:
    """Publishes a bag's messages on ``node`` with their recorded timing.

    Topics whose message type has no Python package here (``/tf`` without ``tf2_msgs``, a
    custom type) are skipped, each named once in :attr:`skipped` with the reason, and the rest
    is played, as ``ros2 bag play`` does. Nothing is read before playing starts (counts come
    from the bag's metadata) unless ``strict`` asks for the stamps to be checked first; header
    stamp irregularities are counted while the first pass plays (:meth:`stamp_warnings`).

    Args:
        node: the rclpy node that owns the publishers (it need not be spun).
        bag: bag path (rosbag2 folder, ``.mcap``/``.db3``, or ROS 1 ``.bag``).
        topics: topics to play (all when empty).
        exclude: topics not to play.
        remap: recorded topic -> published topic.
        rate: playback speed factor (> 0).
        start_offset_s: skip this many seconds from the bag's start.
        loop: play again from the start after the end (until :meth:`stop`); each pass
            publishes the recorded messages unchanged, so header stamps jump back to the bag's
            first stamp when a pass starts (as with ``ros2 bag play --loop``).
        clock: publish /clock with the bag's time at ``clock_hz``.
        strict: refuse (StampOrderError) a bag whose header stamps repeat or go backwards,
            before anything is published (this reads the stamped topics once before playing);
            otherwise irregular stamps are counted in :attr:`stamp_reports` and played as
            recorded.
    """

    def __init__(
        self,
        node: Node,
        bag: str | Path,
        topics: Sequence[str] = (),
        remap: dict[str, str] | None = None,
        rate: float = 1.0,
        start_offset_s: float = 0.0,
        loop: bool = False,
        clock: bool = False,
        clock_hz: float = 100.0,
        strict: bool = False,
        exclude: Sequence[str] = (),
        reliable: bool = False,
    ) -> None:
        """``reliable``: publish every topic reliable, whatever QoS the bag recorded."""
        if not rate > 0:
            raise BagError(f"--rate must be > 0, got {rate}")
        if start_offset_s < 0:
            raise BagError(f"--start-offset must be >= 0, got {start_offset_s}")
        self.node = node
        self.reader = BagReader(bag)
        self.rate = float(rate)
        self.loop = loop
        self.remap = dict(remap or {})
        self._stop = threading.Event()
        wanted = [absolute_topic(t) for t in topics] or sorted(self.reader.topics)
        for t in wanted:
            self.reader.require(t)
        excluded = {absolute_topic(t) for t in exclude}
        wanted = [t for t in wanted if t not in excluded]
        self.skipped: dict[str, str] = {}
        classes = {}
        for t in wanted:
            try:
                classes[t] = message_class(self.reader.topics[t].msgtype)
            except UnknownTypeError as err:
                self.skipped[t] = str(err)
        self.topics = [t for t in wanted if t in classes]
        if not self.topics:
            why = "; ".join(f"{t}: {r}" for t, r in self.skipped.items()) or "no topic selected"
            raise BagError(f"nothing to play from {self.reader.path} ({why})")
        self.stamp_reports: dict[str, StampReport] = {}
        self._stamped = [t for t in self.topics if has_header(self.reader.topics[t].msgtype)]
        if strict:
            self._check_stamps_strict()
        self.start_ns = self.reader.start_time_ns + int(round(start_offset_s * 1e9))
        self.publishers = {}
        self.best_effort_images: list[str] = []  # image topics published best effort
        for t in self.topics:
            info = self.reader.topics[t]
            qos = qos_from_recorded(info.qos)
            if reliable:
                qos.reliability = ReliabilityPolicy.RELIABLE
            elif qos.reliability == ReliabilityPolicy.BEST_EFFORT and info.msgtype == IMAGE:
                self.best_effort_images.append(t)
            self.publishers[t] = node.create_publisher(classes[t], self.remap.get(t, t), qos)
        # messages per pass from the metadata (unknown with a start offset: no pre-pass)
        self.total: int | None = (
            sum(self.reader.topics[t].count for t in self.topics) if start_offset_s == 0 else None
        )
        self._clock_pub = None
        self._clock_hz = clock_hz
        self._bag_now_ns = self.start_ns
        if clock:
            from rosgraph_msgs.msg import Clock

            self._clock_cls = Clock
            self._clock_pub = node.create_publisher(
                Clock, "/clock", QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE)
            )

    def _check_stamps_strict(self) -> None:
        checker = StampChecker()
        for i, msg in enumerate(self.reader.messages(self._stamped)):
            checker.check(msg.topic, header_stamp_ns(msg.data), i)

    def start_warnings(self) -> list[str]:
        """One line per skipped topic (its name and why it cannot be played here) and one per
        image topic published best effort (large frames may be lost on this host)."""
        lines = [f"warning: skipping {t}: {reason}" for t, reason in sorted(self.skipped.items())]
        lines += [
            f"warning: {t} was recorded best effort and is published best effort: a subscriber "
            "on this host that receives through Fast DDS's shared memory loses every frame over "
            "512 KiB (--reliable publishes it reliable)"
            for t in self.best_effort_images
        ]
        return lines

    def stamp_warnings(self) -> list[str]:
        """One line per topic with irregular header stamps in the first pass played (after
        :meth:`run`; empty when all were regular)."""
        lines = []
        for topic, r in sorted(self.stamp_reports.items()):
            if r.irregular:
                lines.append(
                    f"warning: {topic}: {r.repeated} repeated, {r.backwards} backwards and "
                    f"{r.gaps} gap(s) (largest {r.largest_gap_s:.2f} s) in {r.messages} header "
                    "stamps; played as recorded"
                )
        return lines

    def wait_for_subscribers(
        self, topics: Sequence[str], timeout_s: float, settle_s: float = 0.5
    ) -> None:
        """Wait until every (published, i.e. remapped) topic in ``topics`` has a subscriber.

        The publisher sees a subscriber a moment before the subscriber has matched the
        publisher, and a volatile subscriber drops what arrives in between: after the last
        subscriber appears this waits ``settle_s`` more (seconds) so the first message is kept.
        """
        pubs = {p.topic_name: p for p in self.publishers.values()}
        missing = [absolute_topic(t) for t in topics if absolute_topic(t) not in pubs]
        if missing:
            raise TopicNotFoundError(f"--wait-for topics not published from the bag: {missing}")
        deadline = time.monotonic() + timeout_s
        while not self._stop.is_set():
            waiting = [t for t in topics if pubs[absolute_topic(t)].get_subscription_count() == 0]
            if not waiting:
                self._stop.wait(settle_s)
                return
            if time.monotonic() > deadline:
                raise BagError(f"no subscriber on {', '.join(waiting)} after {timeout_s:.0f} s")
            time.sleep(0.05)

    def stop(self) -> None:
        self._stop.set()

    def _clock_loop(self, base_wall: list[float]) -> None:
        period = 1.0 / self._clock_hz
        while not self._stop.is_set():
            now = self.start_ns + int((time.monotonic() - base_wall[0]) * self.rate * 1e9)
            msg = self._clock_cls()
            msg.clock.sec, msg.clock.nanosec = divmod(max(now, 0), 1_000_000_000)
            self._clock_pub.publish(msg)
            time.sleep(period)

    def run(self, progress: bool = True, hold: Callable[[RawMessage], None] | None = None) -> int:
        """Play (blocking); returns the number of messages published.

        ``hold``: called with each message when its time has come, just before it is published;
        it may block (the demo waits there for the node's answer to the pair before), and the
        messages after it are then published as soon as their time has come.
        """
        published = 0
        base_wall = [time.monotonic()]
        clock_thread = None
        if self._clock_pub is not None:
            clock_thread = threading.Thread(target=self._clock_loop, args=(base_wall,), daemon=True)
            clock_thread.start()
        bar = tqdm(
            total=self.total,
            unit="msg",
            desc=f"replay {self.reader.path.name} x{self.rate:g}",
            file=sys.stderr,
            disable=not progress,
            dynamic_ncols=True,
        )
        stamped = set(self._stamped)
        stamps: dict[str, list[int]] = {t: [] for t in self._stamped}
        try:
            first_pass = True
            while not self._stop.is_set():
                if not first_pass:  # a new loop: bag time (and /clock) starts again
                    base_wall[0] = time.monotonic()
                for msg in self.reader.messages(self.topics, start_ns=self.start_ns):
                    target = base_wall[0] + (msg.log_time_ns - self.start_ns) / 1e9 / self.rate
                    while not self._stop.is_set():
                        delay = target - time.monotonic()
                        if delay <= 0:
                            break
                        time.sleep(min(delay, 0.05))
                    if hold is not None and not self._stop.is_set():
                        hold(msg)
                    if self._stop.is_set():
                        break
                    self.publishers[msg.topic].publish(msg.data)
                    if first_pass and msg.topic in stamped:
                        stamps[msg.topic].append(header_stamp_ns(msg.data))
                    published += 1
                    bar.update(1)
                    bar.set_postfix_str(
                        f"t={(msg.log_time_ns - self.reader.start_time_ns) / 1e9:.2f}s",
                        refresh=False,
                    )
                if first_pass:
                    self.stamp_reports = {k: stamp_irregularities(s) for k, s in stamps.items()}
                    first_pass = False
                if not self.loop:
                    break
                bar.reset()
        finally:
            if first_pass:  # interrupted in the first pass: report what was played
                self.stamp_reports = {k: stamp_irregularities(s) for k, s in stamps.items()}
            self._stop.set()
            bar.close()
            if clock_thread is not None:
                clock_thread.join(timeout=1.0)
        return published

    def close(self, ack_timeout_s: float = 5.0) -> None:
        """Close the bag and the publishers, after the subscribers acknowledged what was sent.

        A reliable publisher destroyed right after its last publish can take unsent samples
        with it (the last frame of a replay was lost that way under load), so each one first
        waits (up to ``ack_timeout_s``) until every matched reader has acknowledged its samples.
        """
        from rclpy.duration import Duration

        self.reader.close()
        for pub in self.publishers.values():
            try:
                pub.wait_for_all_acked(Duration(nanoseconds=int(ack_timeout_s * 1e9)))
            except Exception:  # noqa: BLE001 - best effort: never keep a closing player alive
                pass
            self.node.destroy_publisher(pub)


def input_remaps(
    reader: BagReader, left: str | None, right: str | None, image: str | None
) -> dict[str, str]:
    """Remaps that publish the chosen recorded image topics under the node's input names.

    ``--left L --right R`` -> ``/left/image_raw`` and ``/right/image_raw``, ``--image I`` ->
    ``/image_raw`` (``.../compressed`` appended for CompressedImage topics). Empty when no
    topic is given. BagError subclasses for a bad combination, a missing or non-image topic.
    """
    if left is None and right is None and image is None:
        return {}
    spec = detect_inputs(reader, None, left, right, image)
    suffix = COMPRESSED_SUFFIX if spec.transport == "compressed" else ""
    return {src: dst + suffix for src, dst in zip(spec.topics, NODE_INPUTS[spec.mode], strict=True)}
