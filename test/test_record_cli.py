"""``sepfm_ros record``: a real subprocess records live topics (real DDS) into a readable bag."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import rclpy
from sensor_msgs.msg import Image
from std_msgs.msg import String

from sepfm_ros.ros.bags.reader import BagReader


def test_record_writes_every_message_of_the_topics_it_was_given(tmp_path, ros_domain_id):
    out = tmp_path / "rec"
    proc = subprocess.Popen(
        [sys.executable, "-m", "sepfm_ros", "record", "-o", str(out), "/rec_test/text",
         "/rec_test/image"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=dict(os.environ),
    )  # fmt: skip
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node("record_cli_test", context=context)
    try:
        pub_text = node.create_publisher(String, "/rec_test/text", 10)
        pub_image = node.create_publisher(Image, "/rec_test/image", 10)
        other = node.create_publisher(String, "/rec_test/not_recorded", 10)
        deadline = time.monotonic() + 30
        while pub_text.get_subscription_count() < 1 or pub_image.get_subscription_count() < 1:
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline, "the recorder never subscribed"
            time.sleep(0.05)
        time.sleep(0.5)  # the recorder's side of discovery
        for i in range(10):
            pub_text.publish(String(data=f"message {i}"))
            pub_image.publish(Image(height=1, width=2, encoding="mono8", step=2, data=[i, i + 1]))
            other.publish(String(data="ignored"))
            time.sleep(0.02)
        time.sleep(0.5)
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
