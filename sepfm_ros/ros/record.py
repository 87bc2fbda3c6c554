"""``sepfm_ros record -o OUT TOPIC...``: write live topics into a bag (like ``ros2 bag record``).

Each topic is subscribed as soon as a publisher of it is discovered, with its message type and a
QoS compatible with every publisher (reliable only when all offer reliable, transient local only
when all do); the offered QoS is stored with the topic. Messages are written as received (raw
CDR, log time = receipt time). Stops on Ctrl-C, SIGTERM or after ``--duration`` seconds.
Samples the middleware reports lost are counted per topic and reported at the end, with the
cause; large best-effort images arrive as in the node (``sepfm_ros.ros.dds``).

The bag is flushed every ``--flush-interval`` seconds (default 1): even a killed recorder leaves
a readable bag with everything up to the last flush; a clean stop keeps everything.

Exit codes: 0 recorded (a topic that never had a publisher is a warning), 1 an error (an output
name that exists or names another format, nothing recorded at all). Ctrl-C is the normal stop.
"""

from __future__ import annotations

import argparse
import signal
import sys
import time
from collections import Counter
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)

from sepfm_ros.ros.bags.errors import BagError
from sepfm_ros.ros.bags.writer import BagWriter, check_output_path
from sepfm_ros.ros.dds import configure_dds
from sepfm_ros.ros.replay import absolute_topic, message_class
from sepfm_ros.ros.signals import raise_keyboard_interrupt

_INF = QosTime(2147483647, 4294967295)


def _recorded_qos(endpoint_qos: Any) -> Qos:
    """rclpy QoSProfile of a publisher -> rosbags Qos (what the bag stores)."""
    rel = (
        QosReliability.BEST_EFFORT
        if endpoint_qos.reliability == ReliabilityPolicy.BEST_EFFORT
        else QosReliability.RELIABLE
    )
    dur = (
        QosDurability.TRANSIENT_LOCAL
        if endpoint_qos.durability == DurabilityPolicy.TRANSIENT_LOCAL
        else QosDurability.VOLATILE
    )
    return Qos(
        QosHistory.KEEP_LAST,
        int(endpoint_qos.depth) or 10,
        rel,
        dur,
        _INF,
        _INF,
        QosLiveliness.AUTOMATIC,
        _INF,
        False,
    )


class Recorder:
    """Subscribes ``topics`` on ``node`` (once discovered) and writes them to ``writer``.

    Call :meth:`discover` periodically (a timer does it when ``node`` is spun); ``counts`` holds
    messages received per topic, ``lost`` samples the middleware reported lost.
    """

    def __init__(self, node: Node, writer: BagWriter, topics: Sequence[str]) -> None:
        self.node = node
        self.writer = writer
        self.topics = [absolute_topic(t) for t in topics]
        self.subscriptions: dict[str, Any] = {}
        self.counts: Counter[str] = Counter()
        self.lost: Counter[str] = Counter()
        self._timer = node.create_timer(0.1, self.discover)
        self._flush_timer = None
        if writer.flush_interval_s:
            self._flush_timer = node.create_timer(writer.flush_interval_s, writer.flush)
        self.discover()

    def discover(self) -> None:
        """Subscribe to every wanted topic that has a publisher now."""
        pending = [t for t in self.topics if t not in self.subscriptions]
        if not pending:
            return
        types = dict(self.node.get_topic_names_and_types())
        for topic in pending:
            if topic not in types or not types[topic]:
                continue
            msgtype = types[topic][0]
            infos = self.node.get_publishers_info_by_topic(topic)
            if not infos:
                continue
            cls = message_class(msgtype)
            offered = [i.qos_profile for i in infos]
            qos = QoSProfile(depth=100)
            qos.reliability = (
                ReliabilityPolicy.RELIABLE
                if all(q.reliability == ReliabilityPolicy.RELIABLE for q in offered)
                else ReliabilityPolicy.BEST_EFFORT
            )
            qos.durability = (
                DurabilityPolicy.TRANSIENT_LOCAL
                if all(q.durability == DurabilityPolicy.TRANSIENT_LOCAL for q in offered)
                else DurabilityPolicy.VOLATILE
            )
            self.writer.add_topic(topic, msgtype, [_recorded_qos(q) for q in offered])
            events = SubscriptionEventCallbacks(
                message_lost=lambda info, t=topic: self._on_lost(t, int(info.total_count_change))
            )
            self.subscriptions[topic] = self.node.create_subscription(
                cls, topic, lambda data, t=topic: self._on_message(t, data), qos, raw=True,
                event_callbacks=events,
            )  # fmt: skip
            self.node.get_logger().info(f"recording {topic} ({msgtype})")

    def _on_message(self, topic: str, data: bytes) -> None:
        self.writer.write(topic, time.time_ns(), data)
        self.counts[topic] += 1

    def _on_lost(self, topic: str, count: int) -> None:
        self.lost[topic] += max(0, count)

    def ready(self) -> bool:
        """True when every topic is subscribed and matched with at least one publisher."""
        return all(
            t in self.subscriptions and self.subscriptions[t].get_publisher_count() > 0
            for t in self.topics
        )

    def close(self) -> None:
        self.node.destroy_timer(self._timer)
        if self._flush_timer is not None:
            self.node.destroy_timer(self._flush_timer)
        for sub in self.subscriptions.values():
            self.node.destroy_subscription(sub)
        self.writer.close()


def _parse(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        prog="sepfm_ros record",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("topics", nargs="+", metavar="TOPIC")
    p.add_argument("-o", "--output", type=Path, required=True, help="output bag (must not exist)")
    p.add_argument("--duration", type=float, default=0.0, help="stop after S seconds (0 = never)")
    p.add_argument("--flush-interval", type=float, default=1.0, help="seconds (default 1)")
    return p.parse_args(argv)


def main(argv: list[str]) -> int:
    import rclpy
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor

    from sepfm_ros.ros.node_process import own_arguments

    args = _parse(own_arguments("sepfm_ros record", "record", argv))
    try:
        check_output_path(args.output)
        if args.flush_interval <= 0:
            raise BagError("--flush-interval must be > 0")
        writer = BagWriter(args.output, flush_interval_s=args.flush_interval)
    except BagError as err:
        print(f"sepfm_ros record: error: {err}", file=sys.stderr)
        return 1
    dds = configure_dds()  # before rclpy creates the DDS participant
    rclpy.init(args=["record", *argv])
    previous = signal.signal(signal.SIGTERM, raise_keyboard_interrupt)
    node = rclpy.create_node("sepfm_record")
    recorder = Recorder(node, writer, args.topics)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    code = 0
    try:
        deadline = time.monotonic() + args.duration if args.duration > 0 else None
        while rclpy.ok() and (deadline is None or time.monotonic() < deadline):
            executor.spin_once(timeout_sec=0.1)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except BagError as err:
        print(f"sepfm_ros record: error: {err}", file=sys.stderr)
        code = 1
    finally:
        signal.signal(signal.SIGTERM, previous)
        recorder.close()
        node.destroy_node()
        rclpy.try_shutdown()
    missing = [t for t in recorder.topics if t not in recorder.subscriptions]
    summary = ", ".join(f"{t}: {recorder.counts[t]}" for t in recorder.topics)
    print(f"wrote {args.output} ({summary})", file=sys.stderr)
    lost = ", ".join(f"{t}: {recorder.lost[t]}" for t in recorder.topics if recorder.lost[t])
    if lost:
        advice = dds.lost_sample_advice("the recorder")
        print(f"sepfm_ros record: samples lost in transport ({lost}): {advice}", file=sys.stderr)
    if missing:
        print(
            f"sepfm_ros record: warning: never saw a publisher of {', '.join(missing)}",
            file=sys.stderr,
        )
    if code == 0 and not any(recorder.counts.values()):
        print(
            f"sepfm_ros record: error: nothing recorded: no message on {', '.join(args.topics)} "
            f"({args.output} holds no message)",
            file=sys.stderr,
        )
        code = 1
    return code
