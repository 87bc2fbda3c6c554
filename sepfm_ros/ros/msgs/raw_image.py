"""A sensor_msgs/Image read in place from its serialized (CDR) bytes.

rclpy turns a received Image into Python by copying its pixels three times (CDR buffer -> C
message -> ``bytes`` -> ``array.array``), on the executor thread and holding the GIL: 13 ms or
more for a 1920x1080 bgr8 frame. A subscription with ``raw=True`` gets the serialized bytes
instead (one copy, made by rclpy); :func:`read_image` reads the fields from them and gives the
pixels as a numpy view of those bytes (``np.frombuffer``), so the node's decode reads the frame
where it arrived. :class:`SerializedImage` has the fields the package reads of an Image
(``header``, ``height``, ``width``, ``encoding``, ``is_bigendian``, ``step``, ``data``), and keeps
the bytes to be published again as they are (``serialized``) or turned into an rclpy message
(:meth:`SerializedImage.message`).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Any

import numpy as np
from builtin_interfaces.msg import Time
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import Image
from std_msgs.msg import Header

_ENCAPSULATION_BYTES = 4  # CDR encapsulation header: representation id, options
_BYTE_ORDER = {b"\x00\x00": ">", b"\x00\x01": "<"}  # plain CDR big / little endian


@dataclass(frozen=True)
class SerializedImage:
    """A sensor_msgs/Image's fields, its pixels a view of its serialized bytes.

    Attributes:
        header: the image's std_msgs/Header.
        height, width, encoding, is_bigendian, step: as in sensor_msgs/Image.
        data: (step x rows,) uint8, a read-only view into ``serialized`` (no copy).
        serialized: the CDR bytes as received (published again unchanged).
    """

    header: Header
    height: int
    width: int
    encoding: str
    is_bigendian: int
    step: int
    data: np.ndarray
    serialized: bytes

    def message(self) -> Any:
        """The rclpy sensor_msgs/Image (copies the pixels)."""
        return deserialize_message(self.serialized, Image)


class _Reader:
    """Reads CDR primitives from ``buf``; alignment counts from after the encapsulation."""

    def __init__(self, buf: bytes, order: str) -> None:
        self.buf = buf
        self.order = order
        self.pos = _ENCAPSULATION_BYTES

    def _align(self, size: int) -> None:
        offset = self.pos - _ENCAPSULATION_BYTES
        self.pos += -offset % size

    def u32(self) -> int:
        self._align(4)
        (value,) = struct.unpack_from(self.order + "I", self.buf, self.pos)
        self.pos += 4
        return int(value)

    def i32(self) -> int:
        self._align(4)
        (value,) = struct.unpack_from(self.order + "i", self.buf, self.pos)
        self.pos += 4
        return int(value)

    def u8(self) -> int:
        value = self.buf[self.pos]
        self.pos += 1
        return int(value)

    def string(self) -> str:
        n = self.u32()  # length with the terminating NUL
        if n == 0 or self.pos + n > len(self.buf):
            raise ValueError("bad CDR string")
        text = bytes(self.buf[self.pos : self.pos + n - 1]).decode("utf-8")
        self.pos += n
        return text

    def octets(self) -> np.ndarray:
        n = self.u32()
        if self.pos + n > len(self.buf):
            raise ValueError("CDR sequence longer than the message")
        view = np.frombuffer(self.buf, dtype=np.uint8, count=n, offset=self.pos)
        self.pos += n
        return view


def parse_image(serialized: bytes) -> SerializedImage:
    """The fields of a serialized sensor_msgs/Image, pixels in place.

    Raises:
        ValueError: not plain CDR, or truncated.
    """
    order = _BYTE_ORDER.get(bytes(serialized[:2]))
    if order is None or len(serialized) < _ENCAPSULATION_BYTES:
        raise ValueError("not a plain CDR message")
    try:
        r = _Reader(serialized, order)
        sec, nanosec = r.i32(), r.u32()
        frame_id = r.string()
        height, width = r.u32(), r.u32()
        encoding = r.string()
        is_bigendian = r.u8()
        step = r.u32()
        data = r.octets()
    except (struct.error, IndexError, UnicodeDecodeError) as err:
        raise ValueError(f"truncated CDR Image: {err}") from None
    header = Header(stamp=Time(sec=sec, nanosec=nanosec), frame_id=frame_id)
    return SerializedImage(header, height, width, encoding, is_bigendian, step, data, serialized)


def read_image(serialized: bytes) -> Any:
    """What a raw Image subscription's callback gets: a :class:`SerializedImage`, or, for bytes
    this reader does not take (another CDR representation), rclpy's own Image message."""
    try:
        return parse_image(serialized)
    except ValueError:
        return deserialize_message(serialized, Image)
