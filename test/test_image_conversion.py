"""Image / CompressedImage <-> numpy: every listed encoding, row padding, byte order, bad input.

Messages are real rclpy sensor_msgs messages whose bytes are built here by hand (not by the
module's own encoder), so a wrong channel order, Bayer pattern or byte order fails.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from sensor_msgs.msg import CompressedImage, Image

from sepfm_ros.ros.image_conversion import (
    SUPPORTED_ENCODINGS,
    ImageDecodeError,
    check_compressed,
    image_to_array,
    image_to_numpy,
    message_to_numpy,
    numpy_to_compressed,
    numpy_to_image,
)

H, W = 6, 10
RNG = np.random.default_rng(0)
BGR = RNG.integers(0, 256, size=(H, W, 3), dtype=np.uint8)


def make_msg(
    rows: np.ndarray, encoding: str, pad: int = 0, bigendian: bool = False, width: int = W
) -> Image:
    """An Image with ``rows`` (H, row_bytes) uint8 plus ``pad`` junk bytes at each row's end."""
    height, row_bytes = rows.shape
    padded = np.concatenate([rows, np.full((height, pad), 0xAB, np.uint8)], axis=1)
    return Image(
        height=height,
        width=width,
        encoding=encoding,
        is_bigendian=int(bigendian),
        step=row_bytes + pad,
        data=padded.tobytes(),
    )


def as_rows(array: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(array).view(np.uint8).reshape(array.shape[0], -1)


@pytest.mark.parametrize("pad", [0, 3])
@pytest.mark.parametrize(
    ("encoding", "pixels"),
    [
        ("bgr8", BGR),
        ("8UC3", BGR),
        ("rgb8", BGR[..., ::-1]),
        ("bgra8", np.dstack([BGR, np.full((H, W), 7, np.uint8)])),
        ("8UC4", np.dstack([BGR, np.full((H, W), 7, np.uint8)])),
        ("rgba8", np.dstack([BGR[..., ::-1], np.full((H, W), 7, np.uint8)])),
    ],
)
def test_colour_encodings_decode_to_the_same_bgr(encoding, pixels, pad):
    msg = make_msg(as_rows(pixels), encoding, pad)
    np.testing.assert_array_equal(image_to_numpy(msg, "bgr8"), BGR)
    np.testing.assert_array_equal(
        image_to_numpy(msg, "mono8"), cv2.cvtColor(BGR, cv2.COLOR_BGR2GRAY)
    )


@pytest.mark.parametrize("pad", [0, 5])
@pytest.mark.parametrize("encoding", ["mono8", "8UC1"])
def test_mono8(encoding, pad):
    gray = BGR[..., 0]
    msg = make_msg(as_rows(gray), encoding, pad)
    np.testing.assert_array_equal(image_to_numpy(msg, "mono8"), gray)
    np.testing.assert_array_equal(image_to_numpy(msg, "bgr8"), np.dstack([gray] * 3))


@pytest.mark.parametrize("pad", [0, 2])
@pytest.mark.parametrize("bigendian", [False, True])
@pytest.mark.parametrize("encoding", ["mono16", "16UC1"])
def test_16bit_honours_byte_order_and_padding(encoding, bigendian, pad):
    values = RNG.integers(0, 4096, size=(H, W), dtype=np.uint16)  # a 12-bit camera
    stored = values.astype(">u2" if bigendian else "<u2")
    msg = make_msg(as_rows(stored), encoding, pad, bigendian=bigendian)
    raw = image_to_array(msg)
    assert raw.dtype == np.uint16 and raw.dtype.isnative
    np.testing.assert_array_equal(raw, values)
    mono = image_to_numpy(msg, "mono8")
    lo, hi = values.min(), values.max()
    expected = np.round((values.astype(np.float64) - lo) * 255.0 / (hi - lo))
    assert np.abs(mono.astype(np.float64) - expected).max() <= 1.0


def bayer_mosaic(bgr_color: tuple[int, int, int], pattern: str) -> np.ndarray:
    """A uniform-colour Bayer mosaic; ``pattern`` like "rggb" names the 2x2 cell row-major."""
    b, g, r = bgr_color
    value = {"r": r, "g": g, "b": b}
    mosaic = np.zeros((8, 8), np.uint8)
    for i, ch in enumerate(pattern):
        mosaic[i // 2 :: 2, i % 2 :: 2] = value[ch]
    return mosaic


@pytest.mark.parametrize("pattern", ["rggb", "bggr", "gbrg", "grbg"])
def test_bayer_patterns_demosaic_to_the_true_colour(pattern):
    color = (10, 100, 200)
    msg = make_msg(bayer_mosaic(color, pattern), f"bayer_{pattern}8", pad=4, width=8)
    bgr = image_to_numpy(msg, "bgr8")
    np.testing.assert_array_equal(bgr[2:6, 2:6].reshape(-1, 3), np.tile(color, (16, 1)))


def pack_yuv422(y: np.ndarray, u: int, v: int, order: str) -> np.ndarray:
    """(H, W) luma, constant chroma -> (H, 2W) bytes in "uyvy" or "yuyv" order."""
    h, w = y.shape
    out = np.zeros((h, w, 2), np.uint8)
    out[..., 1 if order == "uyvy" else 0] = y
    chroma = np.zeros((h, w), np.uint8)
    chroma[:, 0::2], chroma[:, 1::2] = u, v
    out[..., 0 if order == "uyvy" else 1] = chroma
    return out.reshape(h, 2 * w)


@pytest.mark.parametrize(
    ("encoding", "order"),
    [("yuv422", "uyvy"), ("uyvy", "uyvy"), ("yuv422_yuy2", "yuyv"), ("yuyv", "yuyv")],
)
def test_yuv422_luma_and_chroma_order(encoding, order):
    y = RNG.integers(16, 236, size=(H, W), dtype=np.uint8)
    msg = make_msg(pack_yuv422(y, 128, 128, order), encoding, pad=6)
    np.testing.assert_array_equal(image_to_numpy(msg, "mono8"), y)
    # strong blue chroma (U high, V low) must come out blue, not red
    flat = np.full((H, W), 120, np.uint8)
    bgr = image_to_numpy(make_msg(pack_yuv422(flat, 200, 90, order), encoding), "bgr8")
    b, g, r = bgr[..., 0].mean(), bgr[..., 1].mean(), bgr[..., 2].mean()
    assert b > g + 40 and b > r + 40


def test_every_supported_encoding_is_covered_here():
    covered = {"bgr8", "8UC3", "rgb8", "bgra8", "8UC4", "rgba8", "mono8", "8UC1", "mono16", "16UC1"}
    covered |= {f"bayer_{p}8" for p in ("rggb", "bggr", "gbrg", "grbg")}
    covered |= {"yuv422", "uyvy", "yuv422_yuy2", "yuyv"}
    covered |= {"32FC1", "64FC1"}
    assert covered == set(SUPPORTED_ENCODINGS)


@pytest.mark.parametrize("encoding", ["32FC1", "64FC1"])
def test_float_images_stretch_finite_range_and_zero_non_finite(encoding):
    dtype = np.float32 if encoding == "32FC1" else np.float64
    values = (np.arange(H * W).reshape(H, W) * 0.5 - 3.0).astype(dtype)
    values[0, 0], values[1, 1], values[2, 2] = np.nan, np.inf, -np.inf
    msg = make_msg(as_rows(values), encoding, pad=2)
    mono = image_to_numpy(msg, "mono8")
    assert mono.dtype == np.uint8 and mono.shape == (H, W)
    assert mono[0, 0] == mono[1, 1] == mono[2, 2] == 0
    assert mono[-1, -1] == 255 and mono[0, 1] == 0  # finite min -> 0, max -> 255
    assert mono[3, 5] > mono[3, 4]  # order kept
    nan = np.full((H, W), np.nan, dtype)
    with pytest.raises(ImageDecodeError) as err:
        image_to_numpy(make_msg(as_rows(nan), encoding))
    assert err.value.kind == "non_finite"


@pytest.mark.parametrize(
    ("change", "kind"),
    [
        ({"height": 0}, "zero_size"),
        ({"width": 0}, "zero_size"),
        ({"encoding": "mpeg7"}, "unknown_encoding"),
        ({"encoding": ""}, "unknown_encoding"),
        ({"step": W * 3 - 1}, "bad_step"),
        ({"data": bytes(W * 3 * H - 1)}, "short_data"),
        ({"data": b""}, "short_data"),
        ({"data": bytes(W * 3 * H + 1)}, "long_data"),
        ({"height": 10**6, "width": 10**6, "step": 3 * 10**6}, "short_data"),
    ],
)
def test_malformed_images_raise_a_clear_error(change, kind):
    msg = make_msg(as_rows(BGR), "bgr8")
    for key, value in change.items():
        setattr(msg, key, value)
    with pytest.raises(ImageDecodeError) as err:
        image_to_numpy(msg)
    assert err.value.kind == kind
    assert str(err.value)


@pytest.mark.parametrize("fmt", ["jpeg", "png"])
def test_compressed_round_trip(fmt):
    smooth = cv2.GaussianBlur(cv2.resize(BGR, (160, 96), interpolation=cv2.INTER_CUBIC), (5, 5), 0)
    msg = numpy_to_compressed(smooth, fmt)
    assert isinstance(msg, CompressedImage) and msg.format == fmt
    bgr = message_to_numpy(msg, "bgr8")
    gray = message_to_numpy(msg, "mono8")
    tol = 0 if fmt == "png" else 12
    assert np.abs(bgr.astype(int) - smooth).mean() <= tol
    expected_gray = cv2.cvtColor(smooth, cv2.COLOR_BGR2GRAY)
    assert np.abs(gray.astype(int) - expected_gray).mean() <= max(tol, 1)


def test_compressed_png_16bit_is_stretched():
    values = (np.arange(H * W, dtype=np.uint16).reshape(H, W) * 50).astype(np.uint16)
    ok, buf = cv2.imencode(".png", values)
    assert ok
    msg = CompressedImage(format="png", data=buf.tobytes())
    mono = message_to_numpy(msg, "mono8")
    assert mono.dtype == np.uint8 and mono.min() == 0 and mono.max() == 255


def _encoded(ext: str) -> bytes:
    return cv2.imencode(ext, cv2.resize(BGR, (64, 48)))[1].tobytes()


@pytest.mark.parametrize(
    ("data", "kind"),
    [
        (b"", "zero_size"),
        (b"not an image", "bad_compressed"),
        (b"\xff\xd8 not really", "bad_compressed"),
        (_encoded(".jpg")[:-200], "truncated_compressed"),
        (_encoded(".png")[:-30], "truncated_compressed"),
        (_encoded(".png")[:40] + bytes(64) + _encoded(".png")[-12:], "bad_compressed"),
    ],
    ids=["empty", "text", "jpeg-soi-only", "jpeg-truncated", "png-truncated", "png-corrupt"],
)
def test_bad_compressed_raise_a_clear_error(data, kind):
    msg = CompressedImage(format="jpeg", data=data)
    with pytest.raises(ImageDecodeError) as err:
        message_to_numpy(msg)
    assert err.value.kind == kind
    if kind != "bad_compressed" or not data.startswith(b"\x89PNG"):
        with pytest.raises(ImageDecodeError):  # caught without decoding
            check_compressed(msg)


@pytest.mark.parametrize("encoding", ["mono8", "bgr8", "mono16", "rgba8"])
def test_numpy_to_image_round_trip(encoding):
    dtype = np.uint16 if encoding == "mono16" else np.uint8
    channels = {"mono8": 1, "bgr8": 3, "mono16": 1, "rgba8": 4}[encoding]
    shape = (H, W) if channels == 1 else (H, W, channels)
    array = RNG.integers(0, 200, size=shape).astype(dtype)
    msg = numpy_to_image(array, encoding)
    np.testing.assert_array_equal(image_to_array(msg), array)


def test_numpy_to_image_rejects_a_mismatched_array():
    with pytest.raises(ValueError, match="needs dtype"):
        numpy_to_image(BGR, "mono8")
