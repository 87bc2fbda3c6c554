"""``sepfm_ros record``: a real subprocess records live topics (real DDS) into a readable bag."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import rclpy
from rclpy.duration import Duration
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import Image
from std_msgs.msg import String

from sepfm_ros.ros.bags.errors import BagError
from sepfm_ros.ros.bags.reader import BagReader
from sepfm_ros.ros.node import dds


def _recorded(bag: Path) -> int:
    """Messages in the flushed part of a bag being recorded (0 before the first flush)."""
    try:
        with BagReader(bag) as reader:
            return reader.message_count
    except BagError:
        return 0


def _wait_subscribed(proc: subprocess.Popen, pubs, timeout: float = 60.0) -> float:
    """Wait until the recorder subscribed to every publisher of ``pubs``; returns the deadline
    (time.monotonic()) for what the test waits for next."""
    deadline = time.monotonic() + timeout
    while any(pub.get_subscription_count() < 1 for pub in pubs):
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, "the recorder never subscribed"
        time.sleep(0.05)
    return deadline


@dataclass
class _Recording:
    """A running ``sepfm_ros record`` and the test's own rclpy node; ``err``: the recorder's
    stderr once it stopped."""

    proc: subprocess.Popen
    node: Any
    err: str = ""


@contextlib.contextmanager
def _recording(
    out: Path, topics: list[str], node_name: str, env: dict[str, str] | None = None
) -> Iterator[_Recording]:
    """Run ``sepfm_ros record -o out TOPICS`` (flushing every 0.2 s) beside a node of the test's
    own context; on exit the recorder is stopped with SIGINT, as a user stops it."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "sepfm_ros", "record", "-o", str(out), "--flush-interval", "0.2",
         *topics],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env or dict(os.environ),
    )  # fmt: skip
    context = rclpy.Context()
    rclpy.init(context=context)
    rec = _Recording(proc, rclpy.create_node(node_name, context=context))
    try:
        yield rec
    finally:
        proc.send_signal(signal.SIGINT)
        _, rec.err = proc.communicate(timeout=30)
        rec.node.destroy_node()
        rclpy.try_shutdown(context=context)


def test_record_writes_every_message_of_the_topics_it_was_given(tmp_path, ros_domain_id):
    out = tmp_path / "rec"
    with _recording(out, ["/rec_test/text", "/rec_test/image"], "record_cli_test") as rec:
        proc, node = rec.proc, rec.node
        pub_text = node.create_publisher(String, "/rec_test/text", 10)
        pub_image = node.create_publisher(Image, "/rec_test/image", 10)
        other = node.create_publisher(String, "/rec_test/not_recorded", 10)
        deadline = _wait_subscribed(proc, [pub_text, pub_image])
        # reliable publishers that have matched the recorder's subscriptions keep the messages
        # until the recorder acknowledges them, however late its side of discovery completes
        for i in range(10):
            pub_text.publish(String(data=f"message {i}"))
            pub_image.publish(Image(height=1, width=2, encoding="mono8", step=2, data=[i, i + 1]))
            other.publish(String(data="ignored"))
        for pub in (pub_text, pub_image):
            assert pub.wait_for_all_acked(Duration(seconds=30)), "the recorder never acknowledged"
        # the recorder flushes a readable segment every 0.2 s: wait until all 20 are on disk
        while _recorded(out) < 20:
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline, f"only {_recorded(out)} of 20 messages recorded"
            time.sleep(0.05)
    assert proc.returncode == 0, rec.err
    assert "Traceback" not in rec.err
    with BagReader(out) as bag:
        assert set(bag.topics) == {"/rec_test/text", "/rec_test/image"}
        texts = [bag.deserialize(m).data for m in bag.messages(["/rec_test/text"])]
        images = [bytes(bag.deserialize(m).data) for m in bag.messages(["/rec_test/image"])]
    assert texts == [f"message {i}" for i in range(10)]
    assert images == [bytes([i, i + 1]) for i in range(10)]


def test_record_keeps_a_best_effort_colour_camera(tmp_path, ros_domain_id):
    """A sensor-data QoS (best-effort) publisher of 640x480 bgr8 frames (900 KiB): over Fast
    DDS's shared memory the recorder got none of them (see sepfm_ros/ros/dds.py); with the
    kernel's limit too small for UDP it says why and what lifts it."""
    out = tmp_path / "rec_colour"
    env = dict(os.environ)
    env.pop("ROS_AUTOMATIC_DISCOVERY_RANGE", None)  # as a user starts it
    rng = np.random.default_rng(0)
    frames = [rng.integers(0, 256, (480, 640, 3), dtype=np.uint8) for _ in range(3)]
    sent = 12
    with _recording(out, ["/rec_be/image_raw"], "record_be_test", env) as rec:
        proc = rec.proc
        pub = rec.node.create_publisher(Image, "/rec_be/image_raw", qos_profile_sensor_data)
        _wait_subscribed(proc, [pub])
        time.sleep(1.0)  # best effort keeps nothing for a reader whose matching is not complete
        for i in range(sent):
            msg = Image(height=480, width=640, encoding="bgr8", step=3 * 640)
            msg.header.frame_id = str(i)
            msg.data = frames[i % 3].tobytes()
            pub.publish(msg)
            time.sleep(0.1)
        time.sleep(1.0)
    err = rec.err
    assert proc.returncode == 0, err
    with BagReader(out) as bag:
        got = [bag.deserialize(m) for m in bag.messages(["/rec_be/image_raw"])]
    if dds.read_rmem_max() < dds.MIN_UDP_SOCKET_BYTES:
        assert dds.RMEM_SYSCTL in err, err
        return
    assert len(got) >= sent - 1, f"recorded {len(got)} of {sent} best-effort bgr8 frames\n{err}"
    for msg in got:
        assert bytes(msg.data) == frames[int(msg.header.frame_id) % 3].tobytes()
