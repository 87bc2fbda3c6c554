"""The node's image subscriptions: topic names as image_transport resolves them, and a QoS that
receives what the publishers offer.

- Names: the base topic (``left/image_raw``) is resolved first, with the node's namespace and
  remaps, and ``/compressed`` is added after, as image_transport does; so
  ``-r left/image_raw:=/cam/left/image_raw transport:=compressed`` subscribes to
  ``/cam/left/image_raw/compressed``.
- Reliability ``auto`` (default): the subscription is created when the first publishers appear,
  reliable when all of them publish reliable and best-effort otherwise, as ``ros2 bag record``
  adapts its QoS. A best-effort reader of a reliable camera loses a whole image whenever one UDP
  fragment of it is lost, which at VGA colour and above is most frames. ``reliable`` and
  ``best_effort`` subscribe at once with that policy. Keep-last with a small depth, so the node
  works on the newest frames; the ``qos_overrides./<topic>.subscription.*`` parameters still
  override every policy.
- Samples lost in transport (the ``message_lost`` event) and publishers with a QoS the
  subscription cannot match (``incompatible_qos``) are reported to callbacks, for
  ``/diagnostics``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.node import Node
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
)
from rclpy.qos_overriding_options import QoSOverridingOptions

RELIABILITIES = ("auto", "reliable", "best_effort")
INPUT_DEPTH = 10  # keep-last depth of an image subscription
DISCOVERY_POLL_S = 0.1  # auto: how often to look for the first publishers


def input_topic(node: Node, base: str, transport: str) -> str:
    """The fully qualified topic of image ``base`` (e.g. ``left/image_raw``) for ``transport``
    (``raw`` or ``compressed``): remaps and namespace apply to the base name."""
    resolved = node.resolve_topic_name(base)
    return resolved + "/compressed" if transport == "compressed" else resolved


def input_qos(reliability: ReliabilityPolicy) -> QoSProfile:
    """Keep-last ``INPUT_DEPTH``, volatile, with ``reliability``."""
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=INPUT_DEPTH,
        reliability=reliability,
        durability=DurabilityPolicy.VOLATILE,
    )


def offered_reliability(profiles: list[Any]) -> ReliabilityPolicy:
    """The reliability that matches every publisher QoS profile in ``profiles``: reliable only
    when all of them are reliable (a reliable reader does not match a best-effort writer)."""
    if profiles and all(p.reliability == ReliabilityPolicy.RELIABLE for p in profiles):
        return ReliabilityPolicy.RELIABLE
    return ReliabilityPolicy.BEST_EFFORT


class InputSubscription:
    """One input of the node: an image or camera_info topic (see the module docstring).

    Args:
        node: the node that owns the subscription.
        topic: fully qualified topic (:func:`input_topic`).
        msg_type: sensor_msgs Image or CompressedImage.
        callback: called with each message.
        reliability: one of RELIABILITIES.
        on_lost: called with (topic, samples lost) on the ``message_lost`` event.
        on_incompatible: called with (topic, policy name) when a publisher cannot be matched.
        on_created: called with (topic, reliability name) when the subscription is created.
    """

    def __init__(
        self,
        node: Node,
        topic: str,
        msg_type: type,
        callback: Callable[[Any], None],
        reliability: str,
        on_lost: Callable[[str, int], None],
        on_incompatible: Callable[[str, str], None],
        on_created: Callable[[str, str], None],
    ) -> None:
        if reliability not in RELIABILITIES:
            raise ValueError(f"reliability must be one of {RELIABILITIES}; got {reliability!r}")
        self._node = node
        self.topic = topic
        self._msg_type = msg_type
        self._callback = callback
        self._on_lost = on_lost
        self._on_incompatible = on_incompatible
        self._on_created = on_created
        self.subscription = None
        self._timer = None
        if reliability == "auto":
            self._timer = node.create_timer(DISCOVERY_POLL_S, self._look_for_publishers)
            self._look_for_publishers()
        else:
            policy = (
                ReliabilityPolicy.RELIABLE
                if reliability == "reliable"
                else ReliabilityPolicy.BEST_EFFORT
            )
            self._create(policy)

    def _look_for_publishers(self) -> None:
        if self.subscription is not None:
            return
        infos = self._node.get_publishers_info_by_topic(self.topic)
        if not infos:
            return
        if self._timer is not None:
            self._timer.cancel()
            self._node.destroy_timer(self._timer)
            self._timer = None
        self._create(offered_reliability([i.qos_profile for i in infos]))

    def _create(self, policy: ReliabilityPolicy) -> None:
        events = SubscriptionEventCallbacks(
            message_lost=lambda info: self._on_lost(self.topic, int(info.total_count_change)),
            incompatible_qos=lambda info: self._on_incompatible(
                self.topic, _policy_name(info.last_policy_kind)
            ),
        )
        self.subscription = self._node.create_subscription(
            self._msg_type,
            self.topic,
            self._callback,
            input_qos(policy),
            event_callbacks=events,
            qos_overriding_options=QoSOverridingOptions.with_default_policies(),
        )
        reliability = self.subscription.qos_profile.reliability
        self._on_created(self.topic, _reliability_name(reliability))

    @property
    def reliability(self) -> str | None:
        """The subscription's reliability (``reliable``/``best_effort``), None before it
        exists."""
        if self.subscription is None:
            return None
        return _reliability_name(self.subscription.qos_profile.reliability)

    def publisher_count(self) -> int:
        """Publishers matched by the subscription (0 before it exists)."""
        return 0 if self.subscription is None else self.subscription.get_publisher_count()


def _reliability_name(policy: ReliabilityPolicy) -> str:
    return "reliable" if policy == ReliabilityPolicy.RELIABLE else "best_effort"


def _policy_name(kind: Any) -> str:
    name = getattr(kind, "name", str(kind))
    return str(name).removeprefix("RMW_QOS_POLICY_").lower()
