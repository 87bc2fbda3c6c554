"""A camera's frames reach the detector without extra copies: the message's data is read in
place, a colour frame becomes grey in one ``cv2.cvtColor`` into the final array, and in motion
mode each frame is converted once (image b of a pair is image a of the next).

Copies are counted by memory, not by time: ``tracemalloc`` sees every numpy and OpenCV array,
so a decode's peak allocation is bounded by the grey images it returns."""

from __future__ import annotations

import array
import tracemalloc
from collections.abc import Callable
from typing import Any, TypeVar

import cv2
import numpy as np
import pytest
from sensor_msgs.msg import Image

from sepfm_ros.ros.msgs.image_conversion import image_to_array, pair_decoded, pair_to_numpy
from sepfm_ros.ros.session.answer import DecodedFrames, DecodedPair, decode_pair

HEIGHT, WIDTH = 1080, 1920
GREY_BYTES = HEIGHT * WIDTH  # one mono8 1080p image; a copy of a colour frame is 3x this
SLACK = 256 * 1024  # Python objects and OpenCV's small buffers: far below one copy
GREY_CODES = {"bgr8": cv2.COLOR_BGR2GRAY, "rgb8": cv2.COLOR_RGB2GRAY}
T = TypeVar("T")


def hd_message(encoding: str, seed: int, pad: int = 0, bytes_per_pixel: int = 3) -> Image:
    """A 1920x1080 rclpy Image of random pixels, ``pad`` junk bytes after each row; ``data`` an
    ``array.array`` as rclpy delivers it."""
    row = WIDTH * bytes_per_pixel + pad
    pixels = np.random.default_rng(seed).integers(0, 256, (HEIGHT, row), dtype=np.uint8)
    msg = Image(height=HEIGHT, width=WIDTH, encoding=encoding, step=row)
    msg.data = array.array("B", pixels.tobytes())
    return msg


def peak_allocation(call: Callable[[], T]) -> tuple[T, int]:
    """``call()`` and the most memory (bytes) it held allocated at once."""
    tracemalloc.start()
    try:
        result = call()
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    return result, peak


def test_pixels_are_a_view_of_the_message_data():
    msg = hd_message("bgr8", 0, pad=64)
    pixels = image_to_array(msg)
    assert pixels.shape == (HEIGHT, WIDTH, 3)
    assert np.shares_memory(pixels, np.frombuffer(msg.data, dtype=np.uint8))


@pytest.mark.parametrize("pad", [0, 64])
@pytest.mark.parametrize("encoding", ["bgr8", "rgb8"])
def test_1080p_colour_pair_becomes_grey_without_a_copy(encoding, pad):
    msg_a, msg_b = hd_message(encoding, 1, pad), hd_message(encoding, 2, pad)
    (grey_a, grey_b), peak = peak_allocation(lambda: pair_to_numpy(msg_a, msg_b, "mono8"))
    # the two grey results and nothing of a colour frame's size (padded rows read in place)
    assert peak < 2 * GREY_BYTES + SLACK, peak
    for msg, grey in ((msg_a, grey_a), (msg_b, grey_b)):
        assert grey.shape == (HEIGHT, WIDTH) and grey.dtype == np.uint8
        colour = np.ascontiguousarray(image_to_array(msg))
        np.testing.assert_array_equal(grey, cv2.cvtColor(colour, GREY_CODES[encoding]))


def motion_pairs(messages: list[Any], frames: DecodedFrames) -> list[DecodedPair]:
    """Decode consecutive frames as the node does in motion mode (keys = frame numbers)."""
    out = []
    for k in range(len(messages) - 1):
        decoded = decode_pair(messages[k], messages[k + 1], False, frames, (k, k + 1))
        assert isinstance(decoded, DecodedPair)
        out.append(decoded)
    return out


def test_motion_converts_each_1080p_frame_once():
    messages = [hd_message("bgr8", seed) for seed in range(3)]
    frames = DecodedFrames()
    first = motion_pairs(messages[:2], frames)[0]
    second, peak = peak_allocation(
        lambda: decode_pair(messages[1], messages[2], False, frames, (1, 2))
    )
    assert isinstance(second, DecodedPair)
    assert second.images[0] is first.images[1]  # frame 1: the previous pair's grey image
    assert peak < GREY_BYTES + SLACK, peak  # only frame 2 converted
    fresh = pair_to_numpy(messages[1], messages[2])
    for got, want in zip(second.images, fresh, strict=True):
        np.testing.assert_array_equal(got, want)
    assert frames.reused == 1


def test_deeper_frames_are_converted_with_each_pairs_range():
    """16-bit frames are mapped to 8 bits over both images of a pair, so a frame's grey image
    differs from pair to pair and is decoded again, exactly as without the cache."""
    rng = np.random.default_rng(5)
    images = [rng.integers(0, 1000 * (k + 1), (48, 64), dtype=np.uint16) for k in range(3)]
    messages = [
        Image(height=48, width=64, encoding="mono16", step=128, data=i.tobytes()) for i in images
    ]
    frames = DecodedFrames()
    decoded = motion_pairs(messages, frames)
    assert frames.reused == 0
    for k, pair in enumerate(decoded):
        want = pair_to_numpy(messages[k], messages[k + 1])
        for got, expected in zip(pair.images, want, strict=True):
            np.testing.assert_array_equal(got, expected)
    assert not np.array_equal(decoded[0].images[1], decoded[1].images[0])


def test_a_reused_8bit_image_leaves_a_deep_partner_unchanged():
    """An 8-bit image a takes no part in the pair's range: b is the same with a reused."""
    grey = np.random.default_rng(6).integers(0, 256, (48, 64), dtype=np.uint8)
    deep = np.random.default_rng(7).integers(0, 4000, (48, 64), dtype=np.uint16)
    msg_a = Image(height=48, width=64, encoding="mono8", step=64, data=grey.tobytes())
    msg_b = Image(height=48, width=64, encoding="mono16", step=128, data=deep.tobytes())
    a, b, reusable_b = pair_decoded(msg_a, msg_b, "mono8", image_a=grey)
    assert a is grey and not reusable_b
    np.testing.assert_array_equal(b, pair_to_numpy(msg_a, msg_b)[1])
