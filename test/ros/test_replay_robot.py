"""``sepfm_ros replay`` of robot bags (written with rosbags in the test) over real DDS.

A robot's bag holds ``/tf`` (tf2_msgs), which has no Python package from the wheels this project
uses: replay skips it with one warning and plays the images and camera_info, in mcap and ROS 1
format; ``-l`` loops (header stamps jump back to the bag's start at every pass). The last test
replays a looping bag into the live node and expects answers after the loop restarted.
"""

from __future__ import annotations

import importlib.util
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from robot_bags import (  # noqa: E402
    LEFT_TOPIC,
    RIGHT_TOPIC,
    bag_path,
    header_stamps,
    write_robot_bag,
)
from ros_helpers import RELIABLE, REPO, Ros, StampListener, start_node  # noqa: E402
from sensor_msgs.msg import CameraInfo, Image  # noqa: E402

from sepfm_msgs.msg import TwoViewEstimate  # noqa: E402
from sepfm_ros.ros.bags.reader import BagReader  # noqa: E402
from sepfm_ros.ros.node.replayer import Replayer  # noqa: E402

N_FRAMES = 4
HAVE_TF2_MSGS = importlib.util.find_spec("tf2_msgs") is not None


@pytest.fixture(scope="module")
def small_frames(shared_data) -> list[tuple[np.ndarray, np.ndarray]]:
    """KITTI stereo frames at half size (replay moves bytes; size does not matter here)."""
    folder = shared_data / "kitti_seq2"
    frames = []
    for i in range(N_FRAMES):
        pair = []
        for side in ("left", "right"):
            img = cv2.imread(str(folder / side / f"{i:06d}.png"), cv2.IMREAD_GRAYSCALE)
            assert img is not None
            pair.append(cv2.resize(img, (img.shape[1] // 2, img.shape[0] // 2)))
        frames.append((pair[0], pair[1]))
    return frames


def _replay(bag: Path, *args: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "sepfm_ros", "replay", str(bag), "--quiet", *args],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=dict(os.environ),
    )


@pytest.mark.parametrize("fmt", ["mcap", "ros1"])
def test_replay_skips_tf_plays_the_rest_and_loops(fmt, small_frames, tmp_path, ros_domain_id):
    bag = write_robot_bag(bag_path(tmp_path, fmt), fmt, small_frames, right_lag_ns=12_000_000)
    info = "/camera/left/camera_info"
    listener = StampListener({LEFT_TOPIC: Image, RIGHT_TOPIC: Image, info: CameraInfo})
    try:
        proc = _replay(bag, "-l", "-r", "4", "--wait-for", LEFT_TOPIC, RIGHT_TOPIC, info)
        deadline = time.monotonic() + 60
        while len(listener.stamps[RIGHT_TOPIC]) < 2 * N_FRAMES + 2:
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline, listener.stamps
            time.sleep(0.05)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=30)
    finally:
        listener.close()
    assert proc.returncode == 130 and "Traceback" not in err, err
    skips = [line for line in err.splitlines() if "warning: skipping" in line]
    if HAVE_TF2_MSGS:
        assert skips == [], err
    else:
        assert len(skips) == 1, err  # one warning for /tf, however many passes
        assert "skipping /tf: message type tf2_msgs/msg/TFMessage is not installed" in skips[0]
    for topic in (LEFT_TOPIC, RIGHT_TOPIC, info):
        one_pass = header_stamps(bag, topic)
        got = listener.stamps[topic]
        # looped: a second pass starts again at the first stamp (stamps go back in time)
        assert got[: 2 * N_FRAMES] == one_pass + one_pass, (topic, got)


def test_replay_exclude_topics_and_nothing_to_play(small_frames, tmp_path, ros_domain_id):
    bag = write_robot_bag(bag_path(tmp_path, "sqlite3"), "sqlite3", small_frames[:2])
    listener = StampListener({LEFT_TOPIC: Image, RIGHT_TOPIC: Image})
    try:
        proc = _replay(bag, "--exclude-topics", RIGHT_TOPIC, "--wait-for", LEFT_TOPIC)
        _, err = proc.communicate(timeout=60)
        deadline = time.monotonic() + 10
        while len(listener.stamps[LEFT_TOPIC]) < 2 and time.monotonic() < deadline:
            time.sleep(0.05)
    finally:
        listener.close()
    assert proc.returncode == 0, err
    assert listener.stamps[LEFT_TOPIC] == header_stamps(bag, LEFT_TOPIC)
    assert listener.stamps[RIGHT_TOPIC] == []
    if not HAVE_TF2_MSGS:
        res = subprocess.run(
            [sys.executable, "-m", "sepfm_ros", "replay", str(bag), "--topics", "/tf"],
            cwd=REPO,
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert res.returncode == 1 and "Traceback" not in res.stderr
        assert "nothing to play" in res.stderr and "tf2_msgs/msg/TFMessage" in res.stderr


def test_replay_loop_into_live_node_keeps_answering(small_frames, tmp_path, ros_domain_id):
    # Needs the node to reset its pairing history when stamps jump back (the loop restarts):
    # without that, every pair of the second pass is dropped as late and this test fails.
    bag = write_robot_bag(bag_path(tmp_path, "mcap"), "mcap", small_frames, period_ns=500_000_000)
    ros = Ros()
    answers: list[int] = []
    proc, _client = start_node(
        "loop_target",
        tmp_path,
        ros,
        {"left": ("/left/image_raw", Image), "right": ("/right/image_raw", Image)},
        "-p",
        "qos_overrides./left/image_raw.subscription.reliability:=reliable",
        "-p",
        "qos_overrides./right/image_raw.subscription.reliability:=reliable",
    )

    def on_estimate(msg) -> None:
        answers.append(msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec)

    ros.node.create_subscription(TwoViewEstimate, "/loop_target/estimate", on_estimate, RELIABLE)
    replay = None
    try:
        replay = _replay(bag, "-l", "--left", LEFT_TOPIC, "--right", RIGHT_TOPIC)
        deadline = time.monotonic() + 60
        while len(answers) < 2 * N_FRAMES + 1 and time.monotonic() < deadline:
            assert replay.poll() is None, replay.communicate()
            time.sleep(0.1)
    finally:
        if replay is not None and replay.poll() is None:
            replay.send_signal(signal.SIGINT)
            replay.communicate(timeout=30)
        proc.stop()
        ros.close()
    first = header_stamps(bag, LEFT_TOPIC)
    # more answers than one pass has pairs, and answers for a pass after a jump back
    assert len(answers) >= 2 * N_FRAMES + 1, (answers, proc.output()[-2000:])
    jumps = [k for k in range(1, len(answers)) if answers[k] < answers[k - 1]]
    assert jumps and set(answers) <= set(first)


def test_replay_left_right_publish_on_the_nodes_inputs(small_frames, tmp_path, ros_domain_id):
    bag = write_robot_bag(bag_path(tmp_path, "ros1"), "ros1", small_frames[:3])
    topics = {"/left/image_raw": Image, "/right/image_raw": Image, LEFT_TOPIC: Image}
    listener = StampListener(topics)
    try:
        proc = _replay(
            bag,
            *("--left", LEFT_TOPIC, "--right", RIGHT_TOPIC, "--topics", LEFT_TOPIC, RIGHT_TOPIC),
            *("--wait-for", "/left/image_raw", "/right/image_raw"),
        )
        _, err = proc.communicate(timeout=60)
        deadline = time.monotonic() + 10
        while len(listener.stamps["/right/image_raw"]) < 3 and time.monotonic() < deadline:
            time.sleep(0.05)
    finally:
        listener.close()
    assert proc.returncode == 0, err
    assert listener.stamps["/left/image_raw"] == header_stamps(bag, LEFT_TOPIC)
    assert listener.stamps["/right/image_raw"] == header_stamps(bag, RIGHT_TOPIC)
    assert listener.stamps[LEFT_TOPIC] == []  # remapped, not published under the recorded name


def test_replay_reads_nothing_before_playing(small_frames, tmp_path, ros_domain_id, monkeypatch):
    # counts come from the metadata and stamps are checked while playing: no pre-pass
    bag = write_robot_bag(bag_path(tmp_path, "mcap"), "mcap", small_frames[:2])
    reads: list[str] = []
    original = BagReader.messages

    def counting(self, *args, **kwargs):
        for msg in original(self, *args, **kwargs):
            reads.append(msg.topic)
            yield msg

    monkeypatch.setattr(BagReader, "messages", counting)
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node("replay_reads", context=context)
    replayer = None
    try:
        replayer = Replayer(node, bag)
        assert reads == []
        played = {LEFT_TOPIC, RIGHT_TOPIC, "/camera/left/camera_info", "/camera/right/camera_info"}
        if HAVE_TF2_MSGS:
            played.add("/tf")
        assert set(replayer.topics) == played
        assert replayer.total == 2 * len(played)
        assert replayer.run(progress=False) == replayer.total
        assert len(reads) == replayer.total  # each message read once, to publish it
        assert replayer.stamp_warnings() == []
        assert set(replayer.stamp_reports) == played - {"/tf"}
    finally:
        if replayer is not None:
            replayer.close(ack_timeout_s=0.5)
        node.destroy_node()
        rclpy.try_shutdown(context=context)
