"""Record live topics into a bag with their offered QoS (:class:`Recorder`)."""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Sequence
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

from sepfm_ros.ros.bags.writer import BagWriter
from sepfm_ros.ros.node.replayer import (
    absolute_topic,
    message_class,
)

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
