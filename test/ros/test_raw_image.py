"""An Image read in place from its serialized bytes (what the node's raw subscriptions get)
has rclpy's fields and the pixels as a view of the bytes, with no copy."""

from __future__ import annotations

import array
import tracemalloc

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import Image
from std_msgs.msg import Header

from sepfm_ros.ros.msgs.image_conversion import image_to_array, pair_to_numpy
from sepfm_ros.ros.msgs.raw_image import SerializedImage, parse_image, read_image

FIELDS = ("height", "width", "encoding", "is_bigendian", "step")


def image(frame_id: str, encoding: str, height: int, width: int, step: int, seed: int) -> Image:
    rows = np.random.default_rng(seed).integers(0, 256, height * step, dtype=np.uint8)
    msg = Image(
        header=Header(stamp=Time(sec=-3 + seed, nanosec=999_999_999), frame_id=frame_id),
        height=height, width=width, encoding=encoding, is_bigendian=seed % 2, step=step,
    )  # fmt: skip
    msg.data = array.array("B", rows.tobytes())
    return msg


@pytest.mark.parametrize("frame_id", ["", "c", "cam", "camera_left_optical"])
@pytest.mark.parametrize(
    ("encoding", "height", "width", "step"),
    [("bgr8", 3, 5, 17), ("mono16", 2, 3, 6), ("8UC3", 4, 2, 6), ("yuv422_yuy2", 1, 2, 4)],
)
def test_fields_and_pixels_are_rclpys(frame_id, encoding, height, width, step):
    msg = image(frame_id, encoding, height, width, step, seed=len(frame_id))
    serialized = serialize_message(msg)
    read = parse_image(serialized)
    for name in FIELDS:
        assert getattr(read, name) == getattr(msg, name), name
    assert read.header == msg.header
    assert bytes(read.data) == bytes(msg.data)
    assert np.shares_memory(read.data, np.frombuffer(serialized, dtype=np.uint8))
    assert read.message() == deserialize_message(serialized, Image)


def test_1080p_frame_is_read_without_copying_its_pixels():
    serialized = serialize_message(image("camera", "bgr8", 1080, 1920, 5760, seed=1))
    tracemalloc.start()
    try:
        read = read_image(serialized)
        pixels = image_to_array(read)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert isinstance(read, SerializedImage)
    assert peak < 64 * 1024, peak  # fields only: the 6 MB of pixels stay where they arrived
    assert np.shares_memory(pixels, np.frombuffer(serialized, dtype=np.uint8))
    grey, _ = pair_to_numpy(read, read)
    want, _ = pair_to_numpy(deserialize_message(serialized, Image), read)
    np.testing.assert_array_equal(grey, want)


def test_bytes_it_does_not_read_go_to_rclpy():
    serialized = serialize_message(image("cam", "mono8", 2, 2, 2, seed=0))
    with pytest.raises(ValueError):
        parse_image(b"\x00\x07" + serialized[2:])  # not plain CDR
    with pytest.raises(ValueError):
        parse_image(serialized[:30])  # truncated
    assert isinstance(read_image(serialized), SerializedImage)
