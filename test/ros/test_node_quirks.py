"""The live node over real DDS on images as other robots' drivers publish them: ``step`` 0
(packed rows), big-endian 16-bit, QOI-compressed. Each pair is answered with an accurate F, and
step 0 is logged once per input, not per frame.
"""

from __future__ import annotations

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from robot_bags import qoi_bytes  # noqa: E402
from ros_helpers import header, image_msg, next_stamp, send_pair, start_node  # noqa: E402
from sensor_msgs.msg import CompressedImage, Image  # noqa: E402

from sepfm_ros.ros.bags.results import gt_error_px  # noqa: E402
from sepfm_ros.synthetic.sequences import pair_fundamental, stereo_sequence  # noqa: E402

STEP_ZERO_NOTE = "images have step 0: read as packed rows"


@pytest.fixture(scope="module")
def frames():
    return stereo_sequence(n_frames=3, seed=5)


def _node(name: str, ros, tmp_path, transport: str):
    suffix = "/compressed" if transport == "compressed" else ""
    kind = CompressedImage if transport == "compressed" else Image
    ns = f"/t_{name}"
    inputs = {side: (f"{ns}/{side}/image_raw{suffix}", kind) for side in ("left", "right")}
    args = ["-p", f"image_transport:={transport}", "-p", "seed:=0"]
    for side in ("left", "right"):
        args += ["-r", f"{side}/image_raw{suffix}:={ns}/{side}/image_raw{suffix}"]
    return start_node(name, tmp_path, ros, inputs, *args)


def _assert_accurate(client, stamp: int, frame) -> None:
    values, F, cloud = client.wait_outputs(stamp)
    assert F is not None, values
    pts_a = np.stack([cloud["u_a"], cloud["v_a"]], axis=1).astype(np.float64)
    pts_b = np.stack([cloud["u_b"], cloud["v_b"]], axis=1).astype(np.float64)
    assert len(cloud) >= 30, values
    assert gt_error_px(F, pair_fundamental(*frame.cameras), pts_a, pts_b) < 1.0, values


def _step_zero(msg: Image) -> Image:
    msg.step = 0
    return msg


def test_node_reads_step_zero_and_big_endian_images(frames, ros, tmp_path):
    proc, client = _node("sepfm_step0", ros, tmp_path, "raw")
    try:
        encodings = ["mono8", "16UC1", "mono16"]  # the 16-bit ones big-endian (image_msg)
        for frame, encoding in zip(frames, encodings, strict=True):
            stamp = next_stamp()
            left, right = (_step_zero(image_msg(img, stamp, encoding)) for img in frame.images)
            assert left.is_bigendian == (encoding != "mono8")
            send_pair(client, left, right)
            _assert_accurate(client, stamp, frame)
        for frame in frames[:2]:  # padded big-endian rows with a step, as a driver sends them
            stamp = next_stamp()
            left, right = (image_msg(img, stamp, "mono16", pad=6) for img in frame.images)
            send_pair(client, left, right)
            _assert_accurate(client, stamp, frame)
    finally:
        proc.stop()
    log = proc.output()
    notes = [line for line in log.splitlines() if STEP_ZERO_NOTE in line]
    # once per input topic, though every frame of three encodings had step 0
    assert len(notes) == 2, log
    assert any("left:" in n for n in notes) and any("right:" in n for n in notes), notes
    assert "skipping bad input" not in log


def test_node_decodes_qoi_images(frames, ros, tmp_path):
    proc, client = _node("sepfm_qoi", ros, tmp_path, "compressed")
    try:
        for frame in frames[:2]:
            stamp = next_stamp()
            left, right = (
                CompressedImage(
                    header=header(stamp),
                    format="rgb8; qoi compressed rgb8",
                    data=qoi_bytes(img),
                )
                for img in frame.images
            )
            send_pair(client, left, right)
            _assert_accurate(client, stamp, frame)
    finally:
        proc.stop()
    assert "skipping bad input" not in proc.output()
