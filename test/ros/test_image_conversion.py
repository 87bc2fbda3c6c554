"""Image / CompressedImage <-> numpy: every encoding, row padding, byte order, pairs, bad input.

Messages are real rclpy sensor_msgs messages whose bytes are built here by hand (not by the
module's own encoder), so a wrong channel order, Bayer pattern or byte order fails.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from rosbags.image.image import ENCODINGMAP
from sensor_msgs.msg import CompressedImage, Image

from sepfm_ros.ros.msgs.image_conversion import (
    SUPPORTED_ENCODINGS,
    ImageDecodeError,
    check_compressed,
    image_to_array,
    image_to_numpy,
    message_to_numpy,
    numpy_to_compressed,
    numpy_to_image,
    pair_to_numpy,
    to_uint8,
)

H, W = 6, 10
BGR = np.random.default_rng(0).integers(0, 256, size=(H, W, 3), dtype=np.uint8)
# the same with 0 and 255 in every channel, so that a range stretch maps it onto itself
BGR_FULL = BGR.copy()
BGR_FULL[0, 0], BGR_FULL[0, 1] = 0, 255


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
    rng = np.random.default_rng(1)
    values = rng.integers(0, 4096, size=(H, W), dtype=np.uint16)  # a 12-bit camera
    stored = values.astype(">u2" if bigendian else "<u2")
    msg = make_msg(as_rows(stored), encoding, pad, bigendian=bigendian)
    raw = image_to_array(msg)
    assert raw.dtype == np.uint16 and raw.dtype.isnative
    np.testing.assert_array_equal(raw, values)
    mono = image_to_numpy(msg, "mono8")
    lo, hi = values.min(), values.max()
    expected = np.round((values.astype(np.float64) - lo) * 255.0 / (hi - lo))
    assert np.abs(mono.astype(np.float64) - expected).max() <= 1.0


def bayer_mosaic(bgr_color: tuple[int, int, int], pattern: str, dtype=np.uint8) -> np.ndarray:
    """A uniform-colour Bayer mosaic; ``pattern`` like "rggb" names the 2x2 cell row-major."""
    b, g, r = bgr_color
    value = {"r": r, "g": g, "b": b}
    mosaic = np.zeros((8, 8), dtype)
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
    y = np.random.default_rng(2).integers(16, 236, size=(H, W), dtype=np.uint8)
    msg = make_msg(pack_yuv422(y, 128, 128, order), encoding, pad=6)
    np.testing.assert_array_equal(image_to_numpy(msg, "mono8"), y)
    # strong blue chroma (U high, V low) must come out blue, not red
    flat = np.full((H, W), 120, np.uint8)
    bgr = image_to_numpy(make_msg(pack_yuv422(flat, 200, 90, order), encoding), "bgr8")
    b, g, r = bgr[..., 0].mean(), bgr[..., 1].mean(), bgr[..., 2].mean()
    assert b > g + 40 and b > r + 40


def test_every_supported_encoding_is_covered_here():
    covered = {"bgr8", "8UC3", "rgb8", "bgra8", "8UC4", "rgba8", "mono8", "8UC1", "mono16", "16UC1"}
    covered |= {f"bayer_{p}{d}" for p in ("rggb", "bggr", "gbrg", "grbg") for d in (8, 16)}
    covered |= {"yuv422", "uyvy", "yuv422_yuy2", "yuyv", "nv12", "nv21"}
    covered |= {"bgr16", "rgb16", "bgra16", "rgba16"}
    covered |= {f"{depth}C{n}" for depth, _, _ in GENERIC_DEPTHS for n in (1, 3, 4)}
    covered |= {depth for depth, _, _ in GENERIC_DEPTHS} | {"8U", "8UC1", "8UC3", "8UC4", "32FC1"}
    assert covered == set(SUPPORTED_ENCODINGS)
    # ...which is every encoding rosbags-image names, and every generic type it converts to BGR
    assert set(ENCODINGMAP) <= set(SUPPORTED_ENCODINGS)


@pytest.mark.parametrize("bigendian", [False, True])
@pytest.mark.parametrize(
    ("encoding", "to_bgr"),
    [
        ("bgr16", lambda p: p),
        ("rgb16", lambda p: p[..., ::-1]),
        ("bgra16", lambda p: np.dstack([p, np.full((H, W), 9, p.dtype)])),
        ("rgba16", lambda p: np.dstack([p[..., ::-1], np.full((H, W), 9, p.dtype)])),
    ],
)
def test_16bit_colour_keeps_channel_order_and_is_stretched(encoding, to_bgr, bigendian):
    # a 12-bit colour camera: the pattern x 16 + 7, so the stretch must map it back exactly
    values = to_bgr(BGR_FULL.astype(np.uint16) * 16 + 7).astype(">u2" if bigendian else "<u2")
    msg = make_msg(as_rows(values), encoding, pad=4, bigendian=bigendian)
    np.testing.assert_array_equal(image_to_numpy(msg, "bgr8"), BGR_FULL)
    gray = image_to_numpy(msg, "mono8")
    assert np.abs(gray.astype(int) - cv2.cvtColor(BGR_FULL, cv2.COLOR_BGR2GRAY)).max() <= 1


@pytest.mark.parametrize("pattern", ["rggb", "bggr", "gbrg", "grbg"])
def test_bayer16_patterns_demosaic_to_the_stretched_colour(pattern):
    # 16-bit mosaic of one colour: blue is the darkest (-> 0), red the brightest (-> 255)
    mosaic = bayer_mosaic((1000, 10500, 20000), pattern, np.uint16)
    msg = make_msg(as_rows(mosaic.astype(">u2")), f"bayer_{pattern}16", pad=2, bigendian=True)
    msg.width = 8
    bgr = image_to_numpy(msg, "bgr8")
    expected = (0, round(9500 * 255 / 19000), 255)
    np.testing.assert_array_equal(bgr[2:6, 2:6].reshape(-1, 3), np.tile(expected, (16, 1)))


@pytest.mark.parametrize("depth", [8, 16])
def test_bayer_of_a_grey_scene_demosaics_to_grey(depth):
    # every filter sees the same light: a grey ramp must come out grey (b = g = r), not tinted
    ramp = np.tile(np.arange(16, dtype=np.uint16) * 16, (8, 1))
    ramp = ramp.astype(np.uint8) if depth == 8 else ramp * 256
    msg = make_msg(as_rows(ramp), f"bayer_rggb{depth}", width=16)
    bgr = image_to_numpy(msg, "bgr8").astype(int)
    inner = bgr[2:-2, 2:-2]
    assert np.abs(inner[..., 0] - inner[..., 2]).max() <= 2
    assert np.abs(inner[..., 1] - inner[..., 2]).max() <= 2
    assert np.all(np.diff(inner[..., 1], axis=1) > 0)  # the ramp survives


def yuv420_semiplanar(bgr: np.ndarray, order: str, pad: int) -> np.ndarray:
    """A BGR image -> (1.5 H, W + pad) bytes: Y rows, then interleaved U/V ("nv12") or V/U rows."""
    h, w = bgr.shape[:2]
    i420 = cv2.cvtColor(bgr, cv2.COLOR_BGR2YUV_I420).reshape(-1)  # Y, then U plane, V plane
    y = i420[: h * w].reshape(h, w)
    u = i420[h * w : h * w * 5 // 4].reshape(h // 2, w // 2)
    v = i420[h * w * 5 // 4 :].reshape(h // 2, w // 2)
    first, second = (u, v) if order == "nv12" else (v, u)
    chroma = np.stack([first, second], axis=2).reshape(h // 2, w)
    planes = np.concatenate([y, chroma])
    return np.concatenate([planes, np.full((planes.shape[0], pad), 0xCD, np.uint8)], axis=1)


@pytest.mark.parametrize("pad", [0, 6])
@pytest.mark.parametrize("encoding", ["nv12", "nv21"])
def test_nv12_nv21_luma_exact_and_colour_order(encoding, pad):
    smooth = cv2.GaussianBlur(cv2.resize(BGR, (32, 16), interpolation=cv2.INTER_CUBIC), (7, 7), 0)
    rows = yuv420_semiplanar(smooth, encoding, pad)
    msg = Image(
        height=16, width=32, encoding=encoding, step=32 + pad, data=rows.tobytes(), is_bigendian=0
    )
    luma = cv2.cvtColor(smooth, cv2.COLOR_BGR2YUV_I420)[:16]
    np.testing.assert_array_equal(image_to_numpy(msg, "mono8"), luma)
    # the same samples in the planar I420 layout, decoded by OpenCV, are the reference
    i420 = cv2.cvtColor(smooth, cv2.COLOR_BGR2YUV_I420)
    np.testing.assert_array_equal(
        image_to_numpy(msg, "bgr8"), cv2.cvtColor(i420, cv2.COLOR_YUV2BGR_I420)
    )
    # a blue scene stays blue (swapped U/V would make it red)
    blue = np.zeros((16, 32, 3), np.uint8)
    blue[..., 0] = 220
    msg.data = yuv420_semiplanar(blue, encoding, pad).tobytes()
    b, g, r = image_to_numpy(msg, "bgr8").reshape(-1, 3).mean(axis=0)
    assert b > 150 and r < 60 and g < 60


# (depth, dtype, affine map of the 0..255 pattern into the type's range)
GENERIC_DEPTHS = [
    ("8S", np.int8, lambda p: p.astype(np.int16) - 128),
    ("16U", np.uint16, lambda p: p.astype(np.int64) * 200 + 300),
    ("16S", np.int16, lambda p: p.astype(np.int64) * 100 - 12000),
    ("32S", np.int32, lambda p: p.astype(np.int64) * 100000 - 2_000_000_000),
    ("32F", np.float32, lambda p: p * 0.25 - 3.0),
    ("64F", np.float64, lambda p: p * 1e-3 + 1e6),
]


@pytest.mark.parametrize("bigendian", [False, True])
@pytest.mark.parametrize("channels", [1, 3, 4, None])
@pytest.mark.parametrize(("depth", "dtype", "affine"), GENERIC_DEPTHS, ids=lambda x: str(x))
def test_generic_types_map_their_range_to_8_bits(depth, dtype, affine, channels, bigendian):
    # an affine image of a pattern spanning 0..255 must come back as the pattern
    encoding = depth if channels is None else f"{depth}C{channels}"
    n = channels or 1
    pattern = BGR_FULL[..., 0] if n == 1 else BGR_FULL
    if n == 4:
        pattern = np.dstack([BGR_FULL, BGR_FULL[..., 1]])
    values = affine(pattern).astype(np.dtype(dtype).newbyteorder(">" if bigendian else "<"))
    msg = make_msg(as_rows(values), encoding, pad=3, bigendian=bigendian)
    if n == 1:
        np.testing.assert_array_equal(image_to_numpy(msg, "mono8"), pattern)
    else:
        np.testing.assert_array_equal(image_to_numpy(msg, "bgr8"), pattern[..., :3])


def test_to_uint8_clamps_values_outside_the_range():
    ints = np.array([[-50, 0, 5, 10, 400]], np.int16)
    np.testing.assert_array_equal(to_uint8(ints, 0, 10), [[0, 0, 128, 255, 255]])
    floats = np.array([[-1.0, 0.0, np.nan, 10.0, np.inf]], np.float32)
    np.testing.assert_array_equal(to_uint8(floats, 0, 10), [[0, 0, 0, 255, 0]])


def test_pair_keeps_relative_brightness_of_16bit_images():
    # one scene, two exposures: b collects half the light of a (and has a smaller maximum)
    scene = BGR_FULL[..., 1].astype(np.uint16)
    a, b = scene * 200, scene * 100
    msg_a, msg_b = make_msg(as_rows(a), "mono16"), make_msg(as_rows(b), "16UC1", pad=2)
    out_a, out_b = pair_to_numpy(msg_a, msg_b)
    np.testing.assert_array_equal(out_a, scene)  # a spans the joint range
    np.testing.assert_array_equal(out_b, np.rint(scene / 2.0))  # half as bright, not stretched
    # each image alone is stretched to full range: the two would look equally bright
    np.testing.assert_array_equal(message_to_numpy(msg_b), scene)
    colour_a, colour_b = pair_to_numpy(msg_a, msg_b, "bgr8")
    np.testing.assert_array_equal(colour_b[..., 2], out_b)


def test_pair_of_16bit_png_and_raw_shares_the_range():
    scene = BGR_FULL[..., 2].astype(np.uint16)
    ok, buf = cv2.imencode(".png", scene * 40)
    assert ok
    png = CompressedImage(format="png", data=buf.tobytes())
    raw = make_msg(as_rows(scene * 10), "mono16")
    out_png, out_raw = pair_to_numpy(png, raw)
    np.testing.assert_array_equal(out_png, scene)
    np.testing.assert_array_equal(out_raw, np.rint(scene / 4.0))


def test_pair_of_8bit_images_is_unchanged():
    msg_a = make_msg(as_rows(BGR), "bgr8")
    msg_b = make_msg(as_rows(BGR[..., 0]), "mono8")
    out_a, out_b = pair_to_numpy(msg_a, msg_b)
    np.testing.assert_array_equal(out_a, cv2.cvtColor(BGR, cv2.COLOR_BGR2GRAY))
    np.testing.assert_array_equal(out_b, BGR[..., 0])


def test_pair_with_a_bad_image_raises():
    good = make_msg(as_rows(BGR), "bgr8")
    bad = make_msg(as_rows(BGR), "bgr8")
    bad.step = 1
    with pytest.raises(ImageDecodeError) as err:
        pair_to_numpy(good, bad)
    assert err.value.kind == "bad_step"


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
        ({"encoding": "8UC2"}, "unknown_encoding"),
        ({"encoding": "16SC5"}, "unknown_encoding"),
        ({"encoding": "mono12"}, "unknown_encoding"),
        ({"encoding": "bgr16"}, "bad_step"),  # a 16-bit row needs twice the bytes
        ({"encoding": "32FC3", "step": W * 12, "data": bytes(W * 12 * H + 4)}, "long_data"),
        # nv12 of 10 x 6 px, step 30: step x height x 1.5 bytes, even sizes
        ({"encoding": "nv12", "step": 30}, "short_data"),
        ({"encoding": "nv12", "step": 30, "data": bytes(30 * 9 + 1)}, "long_data"),
        ({"encoding": "nv21", "width": 29, "step": 30, "data": bytes(30 * 9)}, "odd_size"),
        ({"encoding": "nv21", "height": 5, "step": 30, "data": bytes(30 * 9)}, "odd_size"),
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
    array = np.random.default_rng(3).integers(0, 200, size=shape).astype(dtype)
    msg = numpy_to_image(array, encoding)
    np.testing.assert_array_equal(image_to_array(msg), array)


def test_numpy_to_image_rejects_a_mismatched_array():
    with pytest.raises(ValueError, match="needs dtype"):
        numpy_to_image(BGR, "mono8")
