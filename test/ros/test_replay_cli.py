"""``sepfm_ros replay`` options over real DDS: --rate, --start-offset, --topics, --clock, --loop."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

pytest.importorskip("rclpy")

from robot_bags import header_stamps  # noqa: E402
from ros_helpers import StampListener  # noqa: E402
from sensor_msgs.msg import Image  # noqa: E402
from shell_jobs import as_background_job  # noqa: E402

from sepfm_ros.demo import bundled_bags_dir  # noqa: E402

BAG = bundled_bags_dir() / "synthetic_stereo"  # 12 stereo frames at 2 Hz


def _replay(*args: str, background: bool = False) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "sepfm_ros", "replay", str(BAG), "--quiet", *args],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=dict(os.environ),
        preexec_fn=as_background_job if background else None,
    )  # fmt: skip


def test_rate_start_offset_topics_and_clock(ros_domain_id):
    listener = StampListener({"/left/image_raw": Image, "/right/image_raw": Image}, clock=True)
    try:
        proc = _replay("--rate", "4", "--start-offset", "2", "--topics", "/left/image_raw",
                       "--clock", "--wait-for", "/left/image_raw")  # fmt: skip
        _, err = proc.communicate(timeout=120)
        # the player waited for its reliable frames' acknowledgements: wait for the callbacks
        deadline = time.monotonic() + 60
        while len(listener.stamps["/left/image_raw"]) < 8 and time.monotonic() < deadline:
            time.sleep(0.05)
    finally:
        listener.close()
    assert proc.returncode == 0, err
    stamps = header_stamps(BAG, "/left/image_raw")
    # frames every 0.5 s: skipping the first 2 s leaves frames 4..11, in order
    assert listener.stamps["/left/image_raw"] == stamps[4:]
    assert listener.stamps["/right/image_raw"] == []  # not selected
    assert len(listener.clock) >= 5
    assert listener.clock == sorted(listener.clock)
    assert stamps[3] <= listener.clock[0] <= stamps[5]


@pytest.mark.parametrize("background", [False, True], ids=["foreground", "background"])
def test_loop_repeats_until_interrupted(ros_domain_id, background):
    """SIGINT stops a looping replay, also one started as a shell's background job (SIGINT
    inherited ignored)."""
    listener = StampListener({"/left/image_raw": Image, "/right/image_raw": Image}, clock=True)
    try:
        proc = _replay("--loop", "--rate", "8", "--topics", "/left/image_raw",
                       "--wait-for", "/left/image_raw", background=background)  # fmt: skip
        deadline = time.monotonic() + 60
        while len(listener.stamps["/left/image_raw"]) < 30 and time.monotonic() < deadline:
            assert proc.poll() is None, proc.communicate()
            time.sleep(0.05)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=30)
    finally:
        listener.close()
        if proc.poll() is None:  # SIGINT did not stop it
            proc.kill()
            proc.wait()
    got = listener.stamps["/left/image_raw"]
    assert len(got) >= 30, len(got)  # 12 frames per pass: at least two full repeats
    stamps = header_stamps(BAG, "/left/image_raw")
    assert got[:24] == stamps + stamps
    assert "Traceback" not in err
    assert proc.returncode == 130 and "interrupted" in err, (proc.returncode, err)


def test_best_effort_recording_warns_and_reliable_publishes_reliable(tmp_path, shared_data):
    """A best-effort camera's recording is published best effort (with a warning about large
    frames on this host); ``--reliable`` publishes it reliable, which a reliable subscriber
    (incompatible with a best-effort publisher) then receives in full."""
    import cv2
    from robot_bags import write_camera_bag

    frames = [
        cv2.imread(str(shared_data / f"templeRing/templeR{k:04d}.png"), cv2.IMREAD_COLOR)
        for k in range(1, 7)
    ]
    bag = write_camera_bag(tmp_path / "camera_be", frames, period_ns=100_000_000)
    got = {}
    for flags in ((), ("--reliable",)):
        listener = StampListener({"/camera/image_raw": Image})  # reliable, depth 10
        try:
            proc = subprocess.Popen(
                [sys.executable, "-m", "sepfm_ros", "replay", str(bag), "--quiet", *flags,
                 "--wait-for", "/camera/image_raw", "--wait-timeout", "5"],
                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=dict(os.environ),
            )  # fmt: skip
            _, err = proc.communicate(timeout=60)
            time.sleep(0.5)
        finally:
            listener.close()
        got[flags] = (proc.returncode, err, list(listener.stamps["/camera/image_raw"]))
    code, err, stamps = got[()]
    # the reliable subscriber never matches the best-effort publisher: --wait-for times out
    assert code == 1 and stamps == [], err
    assert "recorded best effort and is published best effort" in err
    code, err, stamps = got[("--reliable",)]
    assert code == 0, err
    assert "published best effort" not in err
    assert stamps == header_stamps(bag, "/camera/image_raw")
