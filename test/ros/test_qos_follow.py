"""``input_reliability:=auto`` follows the graph: when the publishers of an input topic change so
that another reliability is the one all of them match, the subscription is recreated with it, and
the switch is logged and counted in /diagnostics (sepfm_ros/ros/node/subscriptions.py).

A reliable subscription does not match a best-effort publisher; a best-effort one matches both.
"""

from __future__ import annotations

import time

import cv2
import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402
from ros_helpers import RELIABLE, image_msg, start_node  # noqa: E402
from sensor_msgs.msg import Image  # noqa: E402

from sepfm_ros.ros.node.subscriptions import InputSubscription  # noqa: E402

BEST_EFFORT = QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT)
TEMPLE = [f"templeRing/templeR{k:04d}.png" for k in range(1, 21)]
T0 = 1_700_000_000 * 10**9  # stamps of these tests (ns)
PERIOD_NS = 250_000_000
TIMEOUT = 90.0  # s; generous: a loaded 2-core machine


def wait_for(condition, timeout: float = TIMEOUT, what: str = "condition"):
    """Poll ``condition()`` until it returns a truthy value (returned); fails after ``timeout``."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        time.sleep(0.05)
    raise AssertionError(f"{what}: not within {timeout} s")


# --------------------------------------------------------------------------- in process
class Recorder:
    """The callbacks of one InputSubscription, recorded."""

    def __init__(self) -> None:
        self.messages: list[int] = []
        self.created: list[str] = []
        self.switched: list[tuple[str, str]] = []
        self.incompatible: list[str] = []

    def subscribe(self, node, topic: str, reliability: str = "auto") -> InputSubscription:
        return InputSubscription(
            node,
            topic,
            Image,
            lambda m: self.messages.append(m.header.stamp.sec),
            reliability,
            on_lost=lambda t, n: None,
            on_incompatible=lambda t, p: self.incompatible.append(p),
            on_created=lambda t, r: self.created.append(r),
            on_switched=lambda t, old, new: self.switched.append((old, new)),
        )


def _received(sub_rec: Recorder, pub, sec: int) -> bool:
    """Publish a tiny image stamped ``sec`` s and tell whether it arrived (publish again on the
    next poll: a message sent before the subscription matched is lost)."""
    msg = image_msg(np.zeros((4, 4), np.uint8), sec * 10**9)
    pub.publish(msg)
    time.sleep(0.02)
    return sec in sub_rec.messages


def test_auto_subscription_switches_only_when_the_reliability_all_match_changes(ros):
    node = ros.node
    topic = "/qos_follow_unit/image_raw"
    rec = Recorder()
    sub = rec.subscribe(node, topic)
    try:
        assert sub.subscription is None  # no publishers yet
        reliable_a = node.create_publisher(Image, topic, RELIABLE)
        wait_for(lambda: sub.reliability == "reliable", what="reliable subscription")
        wait_for(lambda: _received(rec, reliable_a, 1), what="reliable message")
        # another reliable publisher: the same choice, nothing recreated
        reliable_b = node.create_publisher(Image, topic, RELIABLE)
        wait_for(lambda: len(node.get_publishers_info_by_topic(topic)) == 2)
        wait_for(lambda: _received(rec, reliable_b, 2), what="second reliable publisher")
        assert rec.switched == [] and rec.created == ["reliable"]
        # a best-effort publisher joins: best effort is the one all of them match
        best_effort = node.create_publisher(Image, topic, BEST_EFFORT)
        wait_for(lambda: sub.reliability == "best_effort", what="switch to best effort")
        wait_for(lambda: _received(rec, best_effort, 3), what="best-effort message")
        wait_for(lambda: _received(rec, reliable_a, 4), what="reliable message, best effort")
        assert rec.switched == [("reliable", "best_effort")] and sub.switches == 1
        # the reliability mismatch before the switch is not an incompatible-QoS problem
        assert "reliability" not in rec.incompatible
        # one reliable publisher leaves: best effort still needed
        node.destroy_publisher(reliable_b)
        wait_for(lambda: len(node.get_publishers_info_by_topic(topic)) == 2)
        wait_for(lambda: _received(rec, best_effort, 5), what="best effort still received")
        assert sub.switches == 1
        # the best-effort publisher leaves: back to reliable
        node.destroy_publisher(best_effort)
        wait_for(lambda: sub.reliability == "reliable", what="switch back to reliable")
        wait_for(lambda: _received(rec, reliable_a, 6), what="reliable message again")
        assert rec.switched == [("reliable", "best_effort"), ("best_effort", "reliable")]
        # the last publisher leaves: the subscription stays as it is
        node.destroy_publisher(reliable_a)
        wait_for(lambda: not node.get_publishers_info_by_topic(topic))
        time.sleep(0.5)  # several polls (nothing is expected to happen)
        assert sub.reliability == "reliable" and sub.switches == 2
        assert rec.created == ["reliable", "best_effort", "reliable"]
    finally:
        sub.destroy()


def test_fixed_reliability_does_not_follow(ros):
    node = ros.node
    topic = "/qos_follow_fixed/image_raw"
    rec = Recorder()
    sub = rec.subscribe(node, topic, "reliable")
    try:
        best_effort = node.create_publisher(Image, topic, BEST_EFFORT)
        # the mismatch is reported as incompatible, and the subscription stays reliable
        wait_for(lambda: "reliability" in rec.incompatible, what="incompatible reliability")
        assert sub.reliability == "reliable" and sub.switches == 0 and rec.switched == []
        node.destroy_publisher(best_effort)
    finally:
        sub.destroy()


def test_auto_keeps_the_qos_overrides(ros):
    """A depth override still applies after a switch; a reliability override stops the
    following (the mismatch is reported as incompatible instead)."""
    depth_topic, fixed_topic = "/qos_follow_depth/image_raw", "/qos_follow_fixed_rel/image_raw"
    node = rclpy.create_node(
        "qos_follow_overrides",
        context=ros.context,
        parameter_overrides=[
            Parameter(f"qos_overrides.{depth_topic}.subscription.depth", value=3),
            Parameter(f"qos_overrides.{fixed_topic}.subscription.reliability", value="reliable"),
        ],
    )
    ros.executor.add_node(node)
    depth_rec, fixed_rec = Recorder(), Recorder()
    depth_sub = depth_rec.subscribe(node, depth_topic)
    fixed_sub = fixed_rec.subscribe(node, fixed_topic)
    pubs = []
    try:
        for topic in (depth_topic, fixed_topic):
            pubs.append(ros.node.create_publisher(Image, topic, RELIABLE))
        wait_for(lambda: depth_sub.reliability == "reliable" and fixed_sub.reliability)
        assert depth_sub.subscription.qos_profile.depth == 3
        for topic in (depth_topic, fixed_topic):
            pubs.append(ros.node.create_publisher(Image, topic, BEST_EFFORT))
        wait_for(lambda: depth_sub.reliability == "best_effort", what="switch to best effort")
        assert depth_sub.subscription.qos_profile.depth == 3
        wait_for(lambda: "reliability" in fixed_rec.incompatible, what="incompatible reported")
        assert fixed_sub.reliability == "reliable" and fixed_rec.switched == []
    finally:
        depth_sub.destroy()
        fixed_sub.destroy()
        for pub in pubs:
            ros.node.destroy_publisher(pub)
        ros.executor.remove_node(node)
        node.destroy_node()


# --------------------------------------------------------------------------- the live node
@pytest.fixture(scope="module")
def temple(shared_data):
    frames = [cv2.imread(str(shared_data / rel), cv2.IMREAD_GRAYSCALE) for rel in TEMPLE]
    assert all(f is not None for f in frames)
    return frames


def wait_report(client, predicate, what: str, timeout: float = TIMEOUT) -> dict[str, str]:
    """The first /diagnostics report of the client's node, from now on, for which
    ``predicate(values)`` holds."""
    with client.lock:
        start = len(client.health)

    def found():
        with client.lock:
            return next((v for v in client.health[start:] if predicate(v)), None)

    return wait_for(found, timeout, what)


def answered_one_of(client, publisher, frames, stamps: list[int], first: int) -> int:
    """Publish ``frames`` from ``publisher`` at 4 Hz, with stamps from ``first`` on (appended to
    ``stamps``), until the node answers one of them; returns that stamp. Frames sent before the
    node's subscription matches the publisher are lost, so it keeps publishing."""
    deadline = time.monotonic() + TIMEOUT
    k = 0
    while time.monotonic() < deadline:
        stamp = first + k * PERIOD_NS
        stamps.append(stamp)
        publisher.publish(image_msg(frames[k % len(frames)], stamp))
        k += 1
        next_at = time.monotonic() + PERIOD_NS / 1e9
        while time.monotonic() < next_at:
            with client.lock:
                done = [s for s in stamps if s in client.info]
            if done:
                return done[0]
            time.sleep(0.01)
    raise AssertionError(f"none of {len(stamps)} frames answered within {TIMEOUT} s")


def test_node_auto_follows_a_best_effort_publisher_joining_and_leaving(ros, tmp_path, temple):
    """Motion mode at input_reliability auto: a reliable camera first, then a best-effort
    publisher on the same topic (whose frames today's node never matched), then it leaves."""
    topic = "/qos_follow/image_raw"
    proc, client = start_node(
        "qos_follow",
        tmp_path,
        ros,
        {"image": (topic, Image)},
        "-p",
        "mode:=motion",
        "-r",
        f"image_raw:={topic}",
        "-p",
        "diagnostic_updater.period:=0.5",
        input_qos=RELIABLE,
    )
    best_effort = None
    try:
        health = client.latest_health(after=0.0)
        assert health["input_reliability_image"] == "reliable"
        assert int(health.get("input_qos_switches", 0)) == 0
        reliable_stamps: list[int] = []
        answered_one_of(client, client.pubs["image"], temple[:6], reliable_stamps, T0)

        # a best-effort publisher joins: frames only it sends are answered
        best_effort = ros.node.create_publisher(Image, topic, BEST_EFFORT)
        be_stamps: list[int] = []
        stamp = answered_one_of(client, best_effort, temple[6:14], be_stamps, T0 + 100 * 10**9)
        assert stamp in be_stamps and stamp not in reliable_stamps
        report = wait_report(
            client,
            lambda v: v["input_reliability_image"] == "best_effort",
            "best-effort subscription in /diagnostics",
        )
        assert int(report["input_qos_switches"]) == 1, report
        assert int(report["input_qos_switches_to_best_effort"]) == 1, report
        assert "errors_incompatible_qos" not in report, report
        assert "switched from reliable to best_effort" in proc.output()

        # it leaves: the subscription goes back to reliable, and the camera is answered again
        ros.node.destroy_publisher(best_effort)
        best_effort = None
        report = wait_report(
            client,
            lambda v: v["input_reliability_image"] == "reliable",
            "reliable subscription again in /diagnostics",
        )
        assert int(report["input_qos_switches"]) == 2, report
        assert int(report["input_qos_switches_to_reliable"]) == 1, report
        assert "switched from best_effort to reliable" in proc.output()
        again: list[int] = []
        stamp = answered_one_of(client, client.pubs["image"], temple[14:], again, T0 + 200 * 10**9)
        assert stamp in again
    finally:
        if best_effort is not None:
            ros.node.destroy_publisher(best_effort)
        proc.stop()
