"""The node's image subscriptions: topic names as image_transport resolves them, and a QoS that
receives what the publishers offer.

- Names: the base topic (``left/image_raw``) is resolved first, with the node's namespace and
  remaps, and ``/compressed`` is added after, as image_transport does; so
  ``-r left/image_raw:=/cam/left/image_raw image_transport:=compressed`` subscribes to
  ``/cam/left/image_raw/compressed``.
- Reliability ``auto`` (default): the subscription is created when the first publishers appear,
  reliable when all of them publish reliable and best-effort otherwise, as ``ros2 bag record``
  adapts its QoS. A best-effort reader of a reliable camera loses a whole image whenever one UDP
  fragment of it is lost, which at VGA colour and above is most frames. ``auto`` then follows
  the graph: when the publishers change so that another reliability is the one all of them match
  (a best-effort publisher joins reliable ones, or the last best-effort one leaves), the
  subscription is destroyed and created again with it, and the switch is reported; it is not
  recreated otherwise (a publisher leaving the topic, or one joining with the same reliability,
  changes nothing); a ``qos_overrides`` reliability stops it. The publishers are looked at
  on the node's executor, every ``FOLLOW_POLL_S`` and at once when the subscription reports a
  publisher of incompatible reliability. ``reliable`` and ``best_effort``
  subscribe at once with that policy. Keep-last with a small depth, so the node works on the
  newest frames; the ``qos_overrides./<topic>.subscription.*`` parameters still override every
  policy.
- Samples lost in transport (the ``message_lost`` event) and publishers with a QoS the
  subscription cannot match (``incompatible_qos``) are reported to callbacks, for
  ``/diagnostics``; under ``auto``, a publisher's reliability is not reported as incompatible
  (the subscription follows it).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.node import Node
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSPolicyKind,
    QoSProfile,
    ReliabilityPolicy,
)
from rclpy.qos_overriding_options import QoSOverridingOptions

RELIABILITIES = ("auto", "reliable", "best_effort")
INPUT_DEPTH = 10  # keep-last depth of an image subscription
DISCOVERY_POLL_S = 0.1  # auto: how often to look for the first publishers
FOLLOW_POLL_S = 0.5  # auto: how often to look at the publishers once subscribed


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
        on_created: called with (topic, reliability name) when the subscription is created
            (again after each switch).
        on_switched: ``auto``: called with (topic, old reliability name, new reliability name)
            when the subscription was recreated for the publishers now on the topic.
        parse: when given, the subscription takes the serialized message (rclpy's ``raw``) and
            ``callback`` gets ``parse(bytes)`` (e.g. :func:`~..msgs.raw_image.read_image`,
            which reads an Image's pixels in place instead of rclpy's three copies).
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
        on_switched: Callable[[str, str, str], None] | None = None,
        parse: Callable[[bytes], Any] | None = None,
    ) -> None:
        if reliability not in RELIABILITIES:
            raise ValueError(f"reliability must be one of {RELIABILITIES}; got {reliability!r}")
        self._node = node
        self.topic = topic
        self._msg_type = msg_type
        self._callback = callback
        self._parse = parse
        self._on_lost = on_lost
        self._on_incompatible = on_incompatible
        self._on_created = on_created
        self._on_switched = on_switched
        self.subscription = None
        self._requested: ReliabilityPolicy | None = None  # the policy asked for (auto follows)
        self.switches = 0  #: times ``auto`` recreated the subscription with another reliability
        self._timer = None
        self._soon = None  # auto: a one-shot look at the publishers after an incompatible QoS
        if reliability == "auto":
            # polled on the node's executor, so subscriptions are created and destroyed on the
            # executor thread, between callbacks
            self._timer = node.create_timer(DISCOVERY_POLL_S, self._follow_publishers)
            self._follow_publishers()
        else:
            policy = (
                ReliabilityPolicy.RELIABLE
                if reliability == "reliable"
                else ReliabilityPolicy.BEST_EFFORT
            )
            self._create(policy)

    def _follow_publishers(self) -> None:
        """``auto``: create the subscription for the first publishers, then recreate it when
        the reliability all publishers match changes (none left: keep it as it is)."""
        infos = self._node.get_publishers_info_by_topic(self.topic)
        if not infos:
            return
        wanted = offered_reliability([i.qos_profile for i in infos])
        if self.subscription is None:
            self._create(wanted)
            if self._reliability_overridden():
                self._stop_following()  # the user's qos_overrides fixed the reliability
            elif self._timer is not None:
                self._timer.timer_period_ns = int(FOLLOW_POLL_S * 1e9)
            return
        if wanted == self._requested:
            return
        old = self.reliability
        self._node.destroy_subscription(self.subscription)
        self.subscription = None
        # the reliability parameter declared at the first creation holds that first choice:
        # read the other policies' parameters again, not that one
        self._create(wanted, (QoSPolicyKind.HISTORY, QoSPolicyKind.DEPTH))
        self.switches += 1
        if self._on_switched is not None:
            self._on_switched(self.topic, str(old), _reliability_name(wanted))

    def _reliability_overridden(self) -> bool:
        """Whether a ``qos_overrides./<topic>.subscription.reliability`` parameter was given
        (rclpy keeps the node's parameter overrides in ``_parameter_overrides``)."""
        name = f"qos_overrides.{self.topic}.subscription.reliability"
        return name in getattr(self._node, "_parameter_overrides", {})

    def _stop_following(self) -> None:
        for timer in (self._timer, self._soon):
            if timer is not None:
                timer.cancel()
                self._node.destroy_timer(timer)
        self._timer = self._soon = None

    def _incompatible(self, info: Any) -> None:
        policy = _policy_name(info.last_policy_kind)
        if policy == "reliability" and self._timer is not None:
            # auto: a best-effort publisher joined; look at the publishers at once (from a timer,
            # not from this event of the subscription the look may destroy)
            if self._soon is None:
                self._soon = self._node.create_timer(0.0, self._look_now)
            return
        self._on_incompatible(self.topic, policy)

    def _look_now(self) -> None:
        if self._soon is not None:
            self._soon.cancel()
            self._node.destroy_timer(self._soon)
            self._soon = None
        if self._timer is not None:
            self._follow_publishers()

    def _create(
        self, policy: ReliabilityPolicy, overridable: tuple[QoSPolicyKind, ...] | None = None
    ) -> None:
        """Create the subscription with ``policy``; the ``qos_overrides`` parameters of the
        policies ``overridable`` (default: history, depth, reliability) apply."""
        options = (
            QoSOverridingOptions.with_default_policies()
            if overridable is None
            else QoSOverridingOptions(policy_kinds=overridable)
        )
        events = SubscriptionEventCallbacks(
            message_lost=lambda info: self._on_lost(self.topic, int(info.total_count_change)),
            incompatible_qos=self._incompatible,
        )
        self._requested = policy
        parse, callback = self._parse, self._callback
        self.subscription = self._node.create_subscription(
            self._msg_type,
            self.topic,
            callback if parse is None else lambda data: callback(parse(data)),
            input_qos(policy),
            event_callbacks=events,
            qos_overriding_options=options,
            raw=parse is not None,
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

    def destroy(self) -> None:
        """Stop following the publishers and destroy the subscription."""
        self._stop_following()
        if self.subscription is not None:
            self._node.destroy_subscription(self.subscription)
            self.subscription = None

    def publisher_count(self) -> int:
        """Publishers matched by the subscription (0 before it exists)."""
        return 0 if self.subscription is None else self.subscription.get_publisher_count()


def subscription_values(
    subs: list[InputSubscription], topics: list[str], switches: dict[str, int]
) -> dict[str, Any]:
    """The /diagnostics values of a node's input subscriptions ``subs`` (one per input named in
    ``topics``; none while idle): ``input_publishers``, the publishers matched (the fewest over
    the inputs: a player can wait for it before sending, since a message sent before matching
    is lost); ``input_reliability_<input>``; and ``switches`` (input_reliability auto: the
    subscriptions recreated for a change of the publishers, by the new reliability) in all and
    by kind."""
    values: dict[str, Any] = {
        "input_publishers": min((s.publisher_count() for s in subs), default=0)
    }
    for k, name in enumerate(topics):
        sub = subs[k] if subs else None
        values[f"input_reliability_{name}"] = (
            "idle" if sub is None else sub.reliability or "waiting for publishers"
        )
    values["input_qos_switches"] = sum(switches.values())
    for kind in ("best_effort", "reliable"):
        values[f"input_qos_switches_to_{kind}"] = switches.get(kind, 0)
    return values


def _reliability_name(policy: ReliabilityPolicy) -> str:
    return "reliable" if policy == ReliabilityPolicy.RELIABLE else "best_effort"


def _policy_name(kind: Any) -> str:
    name = getattr(kind, "name", str(kind))
    return str(name).removeprefix("RMW_QOS_POLICY_").lower()
