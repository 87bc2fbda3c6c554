"""sensor_msgs Image / CompressedImage <-> numpy, without cv_bridge.

The encoding table and colour conversions come from ``rosbags-image`` (pure Python, OpenCV).
It targets rosbags' own message classes and reads the data buffer as if rows were unpadded, so
this module adds what it lacks: row padding (``step``), validation with clear errors, and
normalisation of 16-bit images. Messages are read by field access only (``height``, ``width``,
``encoding``, ``is_bigendian``, ``step``, ``data``; ``format`` and ``data`` for compressed), so
rclpy messages and rosbags messages both work.

Supported raw encodings (``SUPPORTED_ENCODINGS``): mono8, mono16, 8UC1, 8UC3, 8UC4, 16UC1, bgr8,
rgb8, bgra8, rgba8, bayer_rggb8/bggr8/gbrg8/grbg8, yuv422 (= uyvy), yuv422_yuy2 (= yuyv), and
32FC1/64FC1 (float images: the finite pixels' range is stretched to 8 bits, NaN/inf become 0).
Compressed: jpeg and png (what image_transport's compressed plugin sends), decoded by OpenCV.

Validation is split so a node can reject most bad messages cheaply on arrival:
:func:`check_image` / :func:`check_compressed` look at fields and a few bytes only; what needs
the pixels (undecodable compressed data, float images without one finite pixel) is found when
decoding.
"""

from __future__ import annotations

import sys
from typing import Any

import cv2
import numpy as np
from rosbags.image import ImageError
from rosbags.image.image import convert_color, to_cvtype

# Generic OpenCV-type encodings read as the named colour layout (the cv_bridge convention).
_GENERIC_ALIASES = {"8UC1": "mono8", "8UC3": "bgr8", "8UC4": "bgra8", "16UC1": "mono16"}

SUPPORTED_ENCODINGS: tuple[str, ...] = (
    "mono8",
    "mono16",
    "8UC1",
    "8UC3",
    "8UC4",
    "16UC1",
    "bgr8",
    "rgb8",
    "bgra8",
    "rgba8",
    "bayer_rggb8",
    "bayer_bggr8",
    "bayer_gbrg8",
    "bayer_grbg8",
    "yuv422",
    "uyvy",
    "yuv422_yuy2",
    "yuyv",
    "32FC1",
    "64FC1",
)

COLOR_SPACES = ("mono8", "bgr8")

# Kinds of bad input, used as keys for error counting (diagnostics) and logging once per kind.
ERROR_KINDS = (
    "zero_size",
    "bad_step",
    "short_data",
    "long_data",
    "unknown_encoding",
    "non_finite",
    "bad_compressed",
    "truncated_compressed",
)

_JPEG_SOI = b"\xff\xd8\xff"
_JPEG_EOI = b"\xff\xd9"
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_PNG_IEND = b"IEND"
# End markers must lie within this many bytes of the end (encoders may pad a little).
_END_MARKER_WINDOW = 64


class ImageDecodeError(ValueError):
    """A message that cannot be turned into an image. ``kind`` is one of ``ERROR_KINDS``."""

    def __init__(self, kind: str, message: str) -> None:
        super().__init__(message)
        self.kind = kind


def _canonical(encoding: str) -> str:
    return _GENERIC_ALIASES.get(encoding, encoding)


def pixel_layout(encoding: str) -> tuple[np.dtype, int]:
    """(dtype, channels per pixel) of a raw encoding; ImageDecodeError("unknown_encoding")."""
    if encoding not in SUPPORTED_ENCODINGS:
        raise ImageDecodeError(
            "unknown_encoding",
            f"unsupported image encoding {encoding!r}; supported: {', '.join(SUPPORTED_ENCODINGS)}",
        )
    _, _, typestr, nchan = to_cvtype(_canonical(encoding))
    return np.dtype(typestr), int(nchan)


def check_image(msg: Any) -> tuple[np.dtype, int]:
    """Validate a sensor_msgs/Image without touching its pixels; return (dtype, channels).

    Raises:
        ImageDecodeError: zero width/height (``zero_size``), step smaller than a row
            (``bad_step``), data shorter than step x height (``short_data``), data longer than
            step x height (``long_data``: the size claim and the data disagree), or an
            unsupported encoding (``unknown_encoding``).
    """
    height, width, step = int(msg.height), int(msg.width), int(msg.step)
    dtype, nchan = pixel_layout(msg.encoding)
    if height <= 0 or width <= 0:
        raise ImageDecodeError("zero_size", f"image has zero size ({width}x{height})")
    row_bytes = width * nchan * dtype.itemsize
    if step < row_bytes:
        raise ImageDecodeError(
            "bad_step",
            f"step {step} is smaller than a row of {width} px x {nchan * dtype.itemsize} B"
            f" = {row_bytes} B ({msg.encoding})",
        )
    size = memoryview(msg.data).nbytes
    if size < step * height:
        raise ImageDecodeError(
            "short_data",
            f"data has {size} B, expected step x height = {step} x {height} = {step * height} B",
        )
    if size > step * height:
        raise ImageDecodeError(
            "long_data",
            f"data has {size} B, more than step x height = {step} x {height} = {step * height} B",
        )
    return dtype, nchan


def check_compressed(msg: Any) -> None:
    """Validate a sensor_msgs/CompressedImage from its first and last bytes (no decoding).

    Raises:
        ImageDecodeError: no data (``zero_size``), data that is neither jpeg nor png
            (``bad_compressed``), or jpeg/png data without its end marker
            (``truncated_compressed``).
    """
    data = memoryview(msg.data).cast("B")
    n = data.nbytes
    if n == 0:
        raise ImageDecodeError("zero_size", f"compressed image ({msg.format!r}) has no data")
    head = bytes(data[:8])
    tail = bytes(data[max(0, n - _END_MARKER_WINDOW) :])
    if head.startswith(_JPEG_SOI):
        if _JPEG_EOI not in tail:
            raise ImageDecodeError(
                "truncated_compressed", f"jpeg data of {n} B has no end marker (truncated)"
            )
    elif head == _PNG_SIGNATURE:
        if _PNG_IEND not in tail:
            raise ImageDecodeError(
                "truncated_compressed", f"png data of {n} B has no IEND chunk (truncated)"
            )
    else:
        raise ImageDecodeError(
            "bad_compressed",
            f"{n} B of compressed image ({msg.format!r}) are neither jpeg nor png "
            f"(first bytes {head[:4].hex()})",
        )


def image_to_array(msg: Any) -> np.ndarray:
    """The pixels of a sensor_msgs/Image as stored: (H, W) or (H, W, C), native byte order.

    Honours row padding (``step`` >= width x bytes per pixel) and ``is_bigendian``. The result
    may be a view of ``msg.data`` (no copy) when no byte swap is needed.

    Raises:
        ImageDecodeError: see :func:`check_image`.
    """
    dtype, nchan = check_image(msg)
    height, width, step = int(msg.height), int(msg.width), int(msg.step)
    row_bytes = width * nchan * dtype.itemsize
    data = np.frombuffer(memoryview(msg.data).cast("B"), dtype=np.uint8)
    rows = data[: step * height].reshape(height, step)[:, :row_bytes]
    order = ">" if msg.is_bigendian else "<"
    pixels = rows.view(dtype.newbyteorder(order))
    shape = (height, width) if nchan == 1 else (height, width, nchan)
    pixels = pixels.reshape(shape)
    if dtype.itemsize > 1 and (order == ">") != (sys.byteorder == "big"):
        pixels = pixels.astype(dtype)  # swap to native order
    return pixels


def _to_mono8_or_bgr8(img: np.ndarray, encoding: str, color_space: str) -> np.ndarray:
    if color_space not in COLOR_SPACES:
        raise ValueError(f"color_space must be one of {COLOR_SPACES}, got {color_space!r}")
    enc = _canonical(encoding)
    if img.dtype.kind == "f":
        img, enc = _float_to_mono8(img), "mono8"
    if img.dtype == np.uint16:
        # 16-bit cameras often use 10 or 12 bits: stretch the image's own range to 8 bits.
        gray16 = img if img.ndim == 2 else None
        if gray16 is not None:
            img = cv2.normalize(gray16, None, 0, 255, cv2.NORM_MINMAX, dtype=cv2.CV_8U)
            enc = "mono8"
    if not img.flags.c_contiguous:
        img = np.ascontiguousarray(img)
    try:
        return np.asarray(convert_color(img, enc, color_space))
    except ImageError as err:  # pragma: no cover - every supported encoding converts
        raise ImageDecodeError("unknown_encoding", str(err)) from err


def _float_to_mono8(img: np.ndarray) -> np.ndarray:
    """(H, W) float image -> uint8: finite range stretched to 0..255, NaN/inf -> 0.

    Raises ImageDecodeError("non_finite") when no pixel is finite.
    """
    finite = np.isfinite(img)
    if not finite.any():
        raise ImageDecodeError("non_finite", f"float image {img.shape[::-1]} has no finite pixel")
    values = img[finite].astype(np.float64)
    low, high = float(values.min()), float(values.max())
    scale = 255.0 / (high - low) if high > low else 0.0
    out = np.zeros(img.shape, np.uint8)
    out[finite] = np.clip(np.rint((values - low) * scale), 0, 255).astype(np.uint8)
    return out


def image_to_numpy(msg: Any, color_space: str = "mono8") -> np.ndarray:
    """A sensor_msgs/Image as mono8 (H, W) uint8 or bgr8 (H, W, 3) uint8.

    Bayer images are demosaiced, YUV 4:2:2 converted, 16-bit images stretched to their range.
    Raises ImageDecodeError for malformed messages (see :func:`image_to_array`).
    """
    return _to_mono8_or_bgr8(image_to_array(msg), msg.encoding, color_space)


def compressed_to_numpy(msg: Any, color_space: str = "mono8") -> np.ndarray:
    """A sensor_msgs/CompressedImage (jpeg, png, ...) as mono8 (H, W) or bgr8 (H, W, 3) uint8.

    Raises:
        ImageDecodeError: see :func:`check_compressed`; data OpenCV cannot decode
            (``bad_compressed``).
    """
    check_compressed(msg)
    data = np.frombuffer(memoryview(msg.data).cast("B"), dtype=np.uint8)
    flag = cv2.IMREAD_GRAYSCALE if color_space == "mono8" else cv2.IMREAD_COLOR
    if "16" in str(msg.format) or "png" in str(msg.format).lower():
        flag = cv2.IMREAD_UNCHANGED  # keep 16-bit png depth; normalised below
    img = cv2.imdecode(data, flag)
    if img is None or img.size == 0:
        raise ImageDecodeError(
            "bad_compressed", f"cannot decode {data.size} B of compressed image ({msg.format!r})"
        )
    if img.ndim == 2:
        return _to_mono8_or_bgr8(img, "mono16" if img.dtype == np.uint16 else "mono8", color_space)
    if img.dtype == np.uint16:
        img = cv2.convertScaleAbs(img, alpha=255.0 / 65535.0)
    encoding = "bgra8" if img.shape[2] == 4 else "bgr8"
    return _to_mono8_or_bgr8(img, encoding, color_space)


def is_compressed(msg: Any) -> bool:
    """True for a CompressedImage-like message (it has ``format``), False for an Image."""
    return hasattr(msg, "format")


def message_to_numpy(msg: Any, color_space: str = "mono8") -> np.ndarray:
    """Image or CompressedImage -> mono8 (H, W) or bgr8 (H, W, 3) uint8. See the two above."""
    if is_compressed(msg):
        return compressed_to_numpy(msg, color_space)
    return image_to_numpy(msg, color_space)


def numpy_to_image(array: np.ndarray, encoding: str, header: Any = None) -> Any:
    """A numpy image -> sensor_msgs/Image (rclpy), unpadded rows, native byte order.

    Args:
        array: (H, W) or (H, W, C) with the dtype and channel count of ``encoding``.
        encoding: any of ``SUPPORTED_ENCODINGS`` or "64FC1"/"32FC1".
        header: std_msgs/Header to copy, or None for an empty one.
    """
    from sensor_msgs.msg import Image

    array = np.ascontiguousarray(array)
    if array.ndim not in (2, 3) or array.shape[0] == 0 or array.shape[1] == 0:
        raise ValueError(f"expected a non-empty (H, W) or (H, W, C) array, got {array.shape}")
    if encoding in ("64FC1", "32FC1"):
        dtype, nchan = np.dtype(np.float64 if encoding == "64FC1" else np.float32), 1
    else:
        dtype, nchan = pixel_layout(encoding)
    channels = 1 if array.ndim == 2 else array.shape[2]
    if array.dtype != dtype or channels != nchan:
        raise ValueError(
            f"encoding {encoding} needs dtype {dtype} with {nchan} channel(s),"
            f" got {array.dtype} with {channels}"
        )
    msg = Image()
    if header is not None:
        msg.header = header
    msg.height, msg.width = int(array.shape[0]), int(array.shape[1])
    msg.encoding = encoding
    msg.is_bigendian = int(sys.byteorder == "big")
    msg.step = int(array.shape[1] * nchan * dtype.itemsize)
    msg.data = array.tobytes()
    return msg


def numpy_to_compressed(array: np.ndarray, fmt: str = "jpeg", header: Any = None) -> Any:
    """A mono8/bgr8 numpy image -> sensor_msgs/CompressedImage (rclpy), ``fmt`` jpeg or png."""
    from sensor_msgs.msg import CompressedImage

    ext = {"jpeg": ".jpg", "jpg": ".jpg", "png": ".png"}.get(fmt)
    if ext is None:
        raise ValueError(f"compressed format must be jpeg or png, got {fmt!r}")
    ok, buf = cv2.imencode(ext, array)
    if not ok:
        raise ValueError(f"OpenCV could not encode a {array.shape} {array.dtype} image as {fmt}")
    msg = CompressedImage()
    if header is not None:
        msg.header = header
    msg.format = "jpeg" if ext == ".jpg" else "png"
    msg.data = buf.tobytes()
    return msg
