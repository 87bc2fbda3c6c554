"""``sepfm_ros record``: a real subprocess records live topics (real DDS) into a readable bag."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import rclpy
from rclpy.duration import Duration
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import Image
from std_msgs.msg import String

from sepfm_ros.ros import dds
from sepfm_ros.ros.bags.errors import BagError
from sepfm_ros.ros.bags.reader import BagReader


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


def test_record_writes_every_message_of_the_topics_it_was_given(tmp_path, ros_domain_id):
    out = tmp_path / "rec"
    proc = subprocess.Popen(
        [sys.executable, "-m", "sepfm_ros", "record", "-o", str(out), "--flush-interval", "0.2",
         "/rec_test/text", "/rec_test/image"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=dict(os.environ),
    )  # fmt: skip
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node("record_cli_test", context=context)
    try:
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
    finally:
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=30)
        node.destroy_node()
        rclpy.try_shutdown(context=context)
    assert proc.returncode == 0, err
    assert "Traceback" not in err
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
    proc = subprocess.Popen(
        [sys.executable, "-m", "sepfm_ros", "record", "-o", str(out), "--flush-interval", "0.2",
         "/rec_be/image_raw"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
    )  # fmt: skip
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node("record_be_test", context=context)
    rng = np.random.default_rng(0)
    frames = [rng.integers(0, 256, (480, 640, 3), dtype=np.uint8) for _ in range(3)]
    sent = 12
    try:
        pub = node.create_publisher(Image, "/rec_be/image_raw", qos_profile_sensor_data)
        _wait_subscribed(proc, [pub])
        time.sleep(1.0)  # best effort keeps nothing for a reader whose matching is not complete
        for i in range(sent):
            msg = Image(height=480, width=640, encoding="bgr8", step=3 * 640)
            msg.header.frame_id = str(i)
            msg.data = frames[i % 3].tobytes()
            pub.publish(msg)
            time.sleep(0.1)
        time.sleep(1.0)
    finally:
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=30)
        node.destroy_node()
        rclpy.try_shutdown(context=context)
    assert proc.returncode == 0, err
    with BagReader(out) as bag:
        got = [bag.deserialize(m) for m in bag.messages(["/rec_be/image_raw"])]
    if dds.read_rmem_max() < dds.MIN_UDP_SOCKET_BYTES:
        assert dds.RMEM_SYSCTL in err, err
        return
    assert len(got) >= sent - 1, f"recorded {len(got)} of {sent} best-effort bgr8 frames\n{err}"
    for msg in got:
        assert bytes(msg.data) == frames[int(msg.header.frame_id) % 3].tobytes()
