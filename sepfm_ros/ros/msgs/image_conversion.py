"""sensor_msgs Image / CompressedImage <-> numpy, without cv_bridge.

The encoding table and colour conversions come from ``rosbags-image`` (pure Python, OpenCV).
It targets rosbags' own message classes and reads the data buffer as if rows were unpadded, so
this module adds what it lacks: row padding (``step``; ``step`` 0 read as packed rows when the
data length agrees, as cv_bridge does), validation with clear errors, and the
mapping of deeper pixels to 8 bits. Messages are read by field access only (``height``,
``width``, ``encoding``, ``is_bigendian``, ``step``, ``data``; ``format`` and ``data`` for
compressed), so rclpy messages and rosbags messages both work.

Raw encodings (:func:`is_supported_encoding`): every one ``rosbags-image`` converts.

- Named: mono8/16, bgr8/16, rgb8/16, bgra8/16, rgba8/16, bayer_{rggb,bggr,gbrg,grbg}{8,16},
  yuv422 (= uyvy), yuv422_yuy2 (= yuyv), nv12 and nv21 (4:2:0: ``height`` x ``width`` is the
  image, even sizes; the data holds the Y plane then the interleaved chroma plane of half the
  rows, both with row stride ``step``, so ``len(data) == step * height * 3 / 2``).
- OpenCV types ``{8U,8S,16U,16S,32S,32F,64F}C{1,3,4}`` (``C1`` may be left out): one channel is
  grey, three are BGR, four BGRA (the cv_bridge convention for 8UC3 / 8UC4).

Pixels deeper than 8 bits (16-bit, signed, float) become 8 bits by one linear map: the range
[min, max] of the finite pixels goes to 0..255, NaN and inf to 0. :func:`message_to_numpy` takes
the range of the one image; :func:`pair_to_numpy` takes it over both images of a pair, so the
two keep their relative brightness (a camera's auto exposure or one bright spot does not give
the pair two contrasts). Compressed: jpeg and png (what image_transport's compressed plugin
sends, 16-bit png included), decoded by OpenCV, and qoi, which OpenCV does not read, decoded by
Pillow; other formats are named in the error.

Validation is split so a node can reject most bad messages cheaply on arrival:
:func:`check_image` / :func:`check_compressed` look at fields and a few bytes only; what needs
the pixels (undecodable compressed data, float images without one finite pixel) is found when
decoding.
"""

from __future__ import annotations

import io
import sys
from typing import Any

import cv2
import numpy as np
from rosbags.image import ImageError
from rosbags.image.image import ENC_RE, ENCODINGMAP, convert_color, to_cvtype

# Generic OpenCV-type encodings read as the named colour layout of their channel count (the
# cv_bridge convention); other channel counts have no colour meaning and are rejected.
_GENERIC_LAYOUT = {1: "mono", 3: "bgr", 4: "bgra"}
# 4:2:0 encodings: chroma rows below the luma rows, half as many.
_YUV420 = ("nv12", "nv21")

NAMED_ENCODINGS: tuple[str, ...] = tuple(ENCODINGMAP)
GENERIC_ENCODINGS: tuple[str, ...] = tuple(
    f"{depth}C{n}" for depth in ("8U", "8S", "16U", "16S", "32S", "32F", "64F") for n in (1, 3, 4)
) + tuple(f"{depth}" for depth in ("8U", "8S", "16U", "16S", "32S", "32F", "64F"))
SUPPORTED_ENCODINGS: tuple[str, ...] = NAMED_ENCODINGS + GENERIC_ENCODINGS

COLOR_SPACES = ("mono8", "bgr8")
# 8-bit colour layouts -> mono8: one cv2.cvtColor call, which reads padded rows in place and
# writes the final array (what rosbags-image's convert_color calls for these, without the copy
# to contiguous rows)
_TO_GREY = {
    "bgr8": cv2.COLOR_BGR2GRAY,
    "rgb8": cv2.COLOR_RGB2GRAY,
    "bgra8": cv2.COLOR_BGRA2GRAY,
    "rgba8": cv2.COLOR_RGBA2GRAY,
}

# Kinds of bad input, used as keys for error counting (diagnostics) and logging once per kind.
ERROR_KINDS = (
    "zero_size",
    "odd_size",
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
_QOI_MAGIC = b"qoif"
_QOI_END = b"\x00" * 7 + b"\x01"
# formats named in the error for compressed data that is not decoded
_OTHER_MAGICS = (
    (b"II*\x00", "tiff"),
    (b"MM\x00*", "tiff"),
    (b"BM", "bmp"),
    (b"GIF8", "gif"),
    (b"\x00\x00\x00\x0cjP  ", "jpeg 2000"),
    (b"\xff\x4f\xff\x51", "jpeg 2000"),
)
# End markers must lie within this many bytes of the end (encoders may pad a little).
_END_MARKER_WINDOW = 64


class ImageDecodeError(ValueError):
    """A message that cannot be turned into an image. ``kind`` is one of ``ERROR_KINDS``."""

    def __init__(self, kind: str, message: str) -> None:
        super().__init__(message)
        self.kind = kind


def is_supported_encoding(encoding: str) -> bool:
    """True for every raw encoding this module decodes (see the module docstring)."""
    if encoding in ENCODINGMAP:
        return True
    match = ENC_RE.fullmatch(encoding)
    return match is not None and int(match.group(2) or 1) in _GENERIC_LAYOUT


def pixel_layout(encoding: str) -> tuple[np.dtype, int]:
    """(dtype, channels per pixel) of a raw encoding; ImageDecodeError("unknown_encoding").

    nv12 / nv21 count as one uint8 channel; their data has 1.5 rows per image row.
    """
    if not is_supported_encoding(encoding):
        raise ImageDecodeError(
            "unknown_encoding",
            f"unsupported image encoding {encoding!r}; supported: the named encodings"
            f" {', '.join(NAMED_ENCODINGS)} and OpenCV types like 8UC3, 16SC1, 32FC1"
            " (1, 3 or 4 channels)",
        )
    _, _, typestr, nchan = to_cvtype(encoding)
    return np.dtype(typestr), int(nchan)


def _data_rows(encoding: str, height: int) -> int:
    """Rows of ``step`` bytes in the data of an image ``height`` rows tall."""
    return height * 3 // 2 if encoding in _YUV420 else height


def row_stride(msg: Any, dtype: np.dtype, nchan: int) -> int:
    """Bytes per data row of a sensor_msgs/Image: ``step``, or packed rows for ``step`` 0.

    Some drivers leave ``step`` 0; cv_bridge and OpenCV then read the rows as packed
    (width x channels x bytes per channel). That reading is taken only when the data length is
    exactly that of packed rows; otherwise ``step`` 0 stays and :func:`check_image` reports it.
    """
    step = int(msg.step)
    if step != 0:
        return step
    packed = int(msg.width) * nchan * dtype.itemsize
    rows = _data_rows(msg.encoding, int(msg.height))
    return packed if packed > 0 and memoryview(msg.data).nbytes == packed * rows else 0


def zero_step_note(msg: Any) -> str | None:
    """The warning to give once per topic when ``msg`` is read with packed rows for ``step``
    0 (see :func:`row_stride`); None for an image with a step, or one that is rejected."""
    if is_compressed(msg) or int(msg.step) != 0:
        return None
    try:
        dtype, nchan = check_image(msg)
    except ImageDecodeError:
        return None
    packed = row_stride(msg, dtype, nchan)
    return (
        f"{msg.encoding} images have step 0: read as packed rows of {packed} B "
        f"({msg.width} px x {nchan * dtype.itemsize} B), as cv_bridge and OpenCV do, since the "
        "data length agrees"
    )


class ZeroStepNotes:
    """:func:`zero_step_note` once per topic (a stream of step-0 images warns once, not per
    frame)."""

    def __init__(self) -> None:
        self._seen: set[str] = set()

    def note(self, topic: str, msg: Any) -> str | None:
        """``topic: <note>`` the first time ``topic`` brings a step-0 image read as packed."""
        if topic in self._seen:
            return None
        text = zero_step_note(msg)
        if text is None:
            return None
        self._seen.add(topic)
        return f"{topic}: {text}"


def check_image(msg: Any) -> tuple[np.dtype, int]:
    """Validate a sensor_msgs/Image without touching its pixels; return (dtype, channels).

    ``step`` 0 with data of exactly packed rows reads as packed rows (:func:`row_stride`).

    Raises:
        ImageDecodeError: zero width/height (``zero_size``), odd width/height of a 4:2:0 image
            (``odd_size``), step smaller than a row (``bad_step``), data shorter than
            step x rows (``short_data``), data longer than step x rows (``long_data``: the size
            claim and the data disagree), or an unsupported encoding (``unknown_encoding``).
            Rows are the height, or 1.5 x the height for nv12 / nv21.
    """
    height, width = int(msg.height), int(msg.width)
    dtype, nchan = pixel_layout(msg.encoding)
    if height <= 0 or width <= 0:
        raise ImageDecodeError("zero_size", f"image has zero size ({width}x{height})")
    if msg.encoding in _YUV420 and (height % 2 or width % 2):
        raise ImageDecodeError(
            "odd_size", f"{msg.encoding} needs an even width and height, got {width}x{height}"
        )
    step = row_stride(msg, dtype, nchan)
    row_bytes = width * nchan * dtype.itemsize
    rows = _data_rows(msg.encoding, height)
    size = memoryview(msg.data).nbytes
    if step < row_bytes:
        packed = " (step 0 reads as packed rows only when the data length agrees)"
        raise ImageDecodeError(
            "bad_step",
            f"step {step} is smaller than a row of {width} px x {nchan * dtype.itemsize} B"
            f" = {row_bytes} B ({msg.encoding})"
            + (
                f"{packed}: data has {size} B, packed rows {row_bytes * rows} B"
                if step == 0
                else ""
            ),
        )
    what = f"step x rows = {step} x {rows} = {step * rows} B"
    if msg.encoding in _YUV420:
        what += f" ({msg.encoding}: 1.5 rows of data per image row)"
    if size < step * rows:
        raise ImageDecodeError("short_data", f"data has {size} B, expected {what}")
    if size > step * rows:
        raise ImageDecodeError("long_data", f"data has {size} B, more than {what}")
    return dtype, nchan


def _named_format(head: bytes) -> str | None:
    """The image format the first bytes of compressed data announce (None: not recognised)."""
    if head.startswith(b"RIFF") and head[8:12] == b"WEBP":
        return "webp"
    for magic, name in _OTHER_MAGICS:
        if head.startswith(magic):
            return name
    return None


def check_compressed(msg: Any) -> None:
    """Validate a sensor_msgs/CompressedImage from its first and last bytes (no decoding).

    Raises:
        ImageDecodeError: no data (``zero_size``), data that is neither jpeg, png nor qoi
            (``bad_compressed``, naming the format when its first bytes tell it), or jpeg / png /
            qoi data without its end marker (``truncated_compressed``).
    """
    data = memoryview(msg.data).cast("B")
    n = data.nbytes
    if n == 0:
        raise ImageDecodeError("zero_size", f"compressed image ({msg.format!r}) has no data")
    head = bytes(data[:12])
    tail = bytes(data[max(0, n - _END_MARKER_WINDOW) :])
    if head.startswith(_JPEG_SOI):
        if _JPEG_EOI not in tail:
            raise ImageDecodeError(
                "truncated_compressed", f"jpeg data of {n} B has no end marker (truncated)"
            )
    elif head.startswith(_PNG_SIGNATURE):
        if _PNG_IEND not in tail:
            raise ImageDecodeError(
                "truncated_compressed", f"png data of {n} B has no IEND chunk (truncated)"
            )
    elif head.startswith(_QOI_MAGIC):
        if not tail.endswith(_QOI_END):
            raise ImageDecodeError(
                "truncated_compressed", f"qoi data of {n} B has no end marker (truncated)"
            )
    else:
        named = _named_format(head)
        what = (
            f"{named} data"
            if named
            else f"neither jpeg, png nor qoi (first bytes {head[:4].hex()})"
        )
        raise ImageDecodeError(
            "bad_compressed",
            f"{n} B of compressed image ({msg.format!r}) are {what}"
            + ("; jpeg, png and qoi are decoded" if named else ""),
        )


def image_to_array(msg: Any) -> np.ndarray:
    """The pixels of a sensor_msgs/Image as stored: (H, W) or (H, W, C), native byte order.

    nv12 / nv21 give the (1.5 H, W) uint8 planes (Y, then interleaved chroma) that OpenCV's
    ``COLOR_YUV2*_NV12`` conversions read. Honours row padding (``step`` >= width x bytes per
    pixel; ``step`` 0 as packed rows, see :func:`row_stride`) and ``is_bigendian``. The result
    may be a view of ``msg.data`` (no copy) when no byte swap is needed.

    Raises:
        ImageDecodeError: see :func:`check_image`.
    """
    dtype, nchan = check_image(msg)
    height, width, step = int(msg.height), int(msg.width), row_stride(msg, dtype, nchan)
    rows = _data_rows(msg.encoding, height)
    row_bytes = width * nchan * dtype.itemsize
    data = np.frombuffer(memoryview(msg.data).cast("B"), dtype=np.uint8)
    packed = data[: step * rows].reshape(rows, step)[:, :row_bytes]
    order = ">" if msg.is_bigendian else "<"
    pixels = packed.view(dtype.newbyteorder(order))
    shape = (rows, width) if nchan == 1 else (rows, width, nchan)
    pixels = pixels.reshape(shape)
    if dtype.itemsize > 1 and (order == ">") != (sys.byteorder == "big"):
        pixels = pixels.astype(dtype)  # swap to native order
    return pixels


def _eight_bit_encoding(encoding: str, nchan: int) -> str:
    """The 8-bit unsigned encoding with ``encoding``'s colour layout (bayer_rggb16 -> ...8)."""
    if encoding in ENCODINGMAP:
        return encoding[:-2] + "8" if encoding.endswith("16") else encoding
    return _GENERIC_LAYOUT[nchan] + "8"


def intensity_range(images: list[np.ndarray]) -> tuple[float, float] | None:
    """[min, max] of the finite pixels over every image that is not uint8.

    Args:
        images: decoded pixel arrays (:func:`image_to_array`), any shape and dtype.

    Returns:
        (low, high) in the images' own units, or None when all images are uint8.

    Raises:
        ImageDecodeError("non_finite"): a float image without one finite pixel.
    """
    low, high = np.inf, -np.inf
    for img in images:
        if img.dtype == np.uint8:
            continue
        if img.dtype.kind == "f":
            finite = np.isfinite(img)
            if not finite.any():
                raise ImageDecodeError(
                    "non_finite", f"float image {img.shape[1::-1]} has no finite pixel"
                )
            values = img[finite] if not finite.all() else img
        else:
            values = img
        low, high = min(low, float(values.min())), max(high, float(values.max()))
    return None if low > high else (low, high)


def to_uint8(img: np.ndarray, low: float, high: float) -> np.ndarray:
    """Map pixel values linearly from [low, high] to 0..255 (rounded, clipped); NaN/inf -> 0.

    Args:
        img: (H, W) or (H, W, C) array of any numeric dtype.
        low, high: the input range; high == low maps everything to 0.

    Returns:
        uint8 array of ``img``'s shape.
    """
    scale = 255.0 / (high - low) if high > low else 0.0
    if img.dtype.kind != "f":
        # saturating and rounding in one pass; values are raised to ``low`` first so that
        # (v - low) * scale >= 0 and the absolute value convertScaleAbs takes changes nothing
        floor = np.ceil(low)
        if floor > np.iinfo(img.dtype).min:
            img = np.maximum(img, img.dtype.type(min(floor, np.iinfo(img.dtype).max)))
        return cv2.convertScaleAbs(img, alpha=scale, beta=-low * scale)
    finite = np.isfinite(img)
    out = np.zeros(img.shape, np.uint8)
    values = img[finite].astype(np.float64)
    out[finite] = np.clip(np.rint((values - low) * scale), 0, 255).astype(np.uint8)
    return out


def _convert(
    img: np.ndarray, encoding: str, color_space: str, value_range: tuple[float, float] | None
) -> np.ndarray:
    """Decoded pixels of ``encoding`` -> mono8 / bgr8, deep pixels mapped by ``value_range``."""
    if color_space not in COLOR_SPACES:
        raise ValueError(f"color_space must be one of {COLOR_SPACES}, got {color_space!r}")
    nchan = 1 if img.ndim == 2 else img.shape[2]
    if img.dtype != np.uint8:
        if value_range is None:
            value_range = intensity_range([img])
        img = to_uint8(img, *value_range)
    enc = _eight_bit_encoding(encoding, nchan)
    if color_space == "mono8" and enc in _TO_GREY:
        return cv2.cvtColor(img, _TO_GREY[enc])  # padded rows read in place, no copy
    if enc == color_space:
        return img  # already mono8 / bgr8: the pixels as they are (a view of the data)
    if not img.flags.c_contiguous:
        img = np.ascontiguousarray(img)
    try:
        return np.asarray(convert_color(img, enc, color_space))
    except (ImageError, cv2.error) as err:  # pragma: no cover - every listed encoding converts
        raise ImageDecodeError("unknown_encoding", f"{encoding}: {err}") from err


def _decode_compressed(msg: Any, color_space: str) -> tuple[np.ndarray, str]:
    """A CompressedImage -> (pixels, encoding of the pixels); 16-bit png keeps its depth."""
    check_compressed(msg)
    data = np.frombuffer(memoryview(msg.data).cast("B"), dtype=np.uint8)
    if bytes(data[:4]) == _QOI_MAGIC:
        return _decode_qoi(data, msg.format)
    flag = cv2.IMREAD_GRAYSCALE if color_space == "mono8" else cv2.IMREAD_COLOR
    if "16" in str(msg.format) or "png" in str(msg.format).lower():
        flag = cv2.IMREAD_UNCHANGED  # keep 16-bit png depth; mapped to 8 bits by the caller
    img = cv2.imdecode(data, flag)
    if img is None or img.size == 0:
        raise ImageDecodeError(
            "bad_compressed", f"cannot decode {data.size} B of compressed image ({msg.format!r})"
        )
    nchan = 1 if img.ndim == 2 else img.shape[2]
    depth = "16" if img.dtype == np.uint16 else "8"
    return img, {1: "mono", 3: "bgr", 4: "bgra"}[nchan] + depth


def _decode_qoi(data: np.ndarray, fmt: str) -> tuple[np.ndarray, str]:
    """QOI data (which OpenCV does not read) -> (H, W, 3|4) uint8 pixels and rgb8 / rgba8, by
    Pillow's QOI reader."""
    from PIL import Image as PilImage

    try:
        with PilImage.open(io.BytesIO(data.tobytes()), formats=["QOI"]) as img:
            img.load()
            pixels = np.asarray(img)
    except (OSError, ValueError, SyntaxError) as err:
        raise ImageDecodeError(
            "bad_compressed", f"cannot decode {data.size} B of qoi data ({fmt!r}): {err}"
        ) from None
    if pixels.ndim != 3 or pixels.shape[2] not in (3, 4) or pixels.size == 0:
        raise ImageDecodeError("bad_compressed", f"qoi data ({fmt!r}) gave {pixels.shape} pixels")
    return pixels, "rgb8" if pixels.shape[2] == 3 else "rgba8"


def _decode(msg: Any, color_space: str) -> tuple[np.ndarray, str]:
    """Image or CompressedImage -> (pixels as stored or decoded, their encoding)."""
    if is_compressed(msg):
        return _decode_compressed(msg, color_space)
    return image_to_array(msg), msg.encoding


def image_to_numpy(msg: Any, color_space: str = "mono8") -> np.ndarray:
    """A sensor_msgs/Image as mono8 (H, W) uint8 or bgr8 (H, W, 3) uint8.

    Bayer images are demosaiced, YUV converted, deeper pixels mapped to 8 bits over the image's
    own range (see the module docstring). Raises ImageDecodeError for malformed messages (see
    :func:`image_to_array`).
    """
    return _convert(image_to_array(msg), msg.encoding, color_space, None)


def compressed_to_numpy(msg: Any, color_space: str = "mono8") -> np.ndarray:
    """A sensor_msgs/CompressedImage (jpeg, png, ...) as mono8 (H, W) or bgr8 (H, W, 3) uint8.

    Raises:
        ImageDecodeError: see :func:`check_compressed`; data OpenCV cannot decode
            (``bad_compressed``).
    """
    img, encoding = _decode_compressed(msg, color_space)
    return _convert(img, encoding, color_space, None)


def is_compressed(msg: Any) -> bool:
    """True for a CompressedImage-like message (it has ``format``), False for an Image."""
    return hasattr(msg, "format")


def message_to_numpy(msg: Any, color_space: str = "mono8") -> np.ndarray:
    """Image or CompressedImage -> mono8 (H, W) or bgr8 (H, W, 3) uint8. See the two above.

    For the two images of a pair use :func:`pair_to_numpy`, which maps both with one range.
    """
    img, encoding = _decode(msg, color_space)
    return _convert(img, encoding, color_space, None)


def pair_to_numpy(
    msg_a: Any, msg_b: Any, color_space: str = "mono8"
) -> tuple[np.ndarray, np.ndarray]:
    """The two images of a pair as mono8 (H, W) or bgr8 (H, W, 3) uint8, with one contrast.

    Like :func:`message_to_numpy` on each, except that pixels deeper than 8 bits (16-bit,
    signed, float) are mapped to 8 bits with one range, [min, max] of the finite pixels of
    both images: two exposures of one scene keep their relative brightness, so a feature's
    two appearances differ as the scene does, not by two independent stretches.

    Raises:
        ImageDecodeError: either message is malformed (see :func:`check_image`,
            :func:`check_compressed`).
    """
    image_a, image_b, _ = pair_decoded(msg_a, msg_b, color_space)
    return image_a, image_b


def pair_decoded(
    msg_a: Any, msg_b: Any, color_space: str = "mono8", image_a: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, bool]:
    """:func:`pair_to_numpy`, reusing image a when an earlier pair decoded it.

    Args:
        image_a: ``msg_a`` as an earlier call returned it for a message whose pixels were 8-bit
            (its third value True): then ``msg_a`` is not decoded again. An 8-bit image takes
            no part in the pair's intensity range, so the result is the same as without it.

    Returns:
        (image a, image b, reusable): ``reusable`` is True when ``msg_b``'s pixels were 8-bit,
        so image b may be passed as ``image_a`` of a later pair with ``msg_b`` as image a.
    """
    if image_a is not None:
        img_b, enc_b = _decode(msg_b, color_space)
        value_range = intensity_range([img_b])
        converted_a = image_a
    else:
        img_a, enc_a = _decode(msg_a, color_space)
        img_b, enc_b = _decode(msg_b, color_space)
        value_range = intensity_range([img_a, img_b])
        converted_a = _convert(img_a, enc_a, color_space, value_range)
    converted_b = _convert(img_b, enc_b, color_space, value_range)
    return converted_a, converted_b, img_b.dtype == np.uint8


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
