"""Message helpers on rclpy message types: stamps, headers, diagnostics, and the ground truth.

The node's per-pair answers are composed in :mod:`sepfm_ros.ros.answer` (typed messages).

- :func:`fundamental_to_image`: a ground-truth F as a 3x3 ``64FC1`` sensor_msgs/Image
  (row-major), the bags' ``/ground_truth/fundamental``; :func:`fundamental_from_image` reads it.
- :func:`health_status`: a diagnostic_msgs/DiagnosticStatus from name/value pairs.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Mapping
from typing import Any

import numpy as np
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from sensor_msgs.msg import Image
from std_msgs.msg import Header


def stamp_ns(stamp: Time) -> int:
    """builtin_interfaces/Time (or any object with ``sec`` and ``nanosec``) -> integer ns.

    The package's one stamp conversion (serialized CDR headers: ``bags.types.header_stamp_ns``).
    """
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def camera_info_topic(image_topic: str) -> str:
    """The ``camera_info`` topic beside an image topic, as image_transport pairs them:
    ``/left/image_raw`` (or ``/left/image_raw/compressed``) -> ``/left/camera_info``."""
    base = image_topic.removesuffix("/compressed")
    parent = base.rsplit("/", 1)[0] if "/" in base else ""
    return parent + "/camera_info"


def copy_header(header: Header) -> Header:
    """An independent copy of a std_msgs/Header."""
    return Header(
        stamp=Time(sec=int(header.stamp.sec), nanosec=int(header.stamp.nanosec)),
        frame_id=str(header.frame_id),
    )


def fundamental_to_image(F: np.ndarray, header: Header) -> Image:
    """F (3, 3) -> sensor_msgs/Image: 64FC1, height = width = 3, row-major, native order."""
    F = np.ascontiguousarray(np.asarray(F, dtype=np.float64))
    if F.shape != (3, 3) or not np.all(np.isfinite(F)):
        raise ValueError(f"F must be a finite 3x3 matrix, got shape {F.shape}")
    return Image(
        header=copy_header(header),
        height=3,
        width=3,
        encoding="64FC1",
        is_bigendian=int(sys.byteorder == "big"),
        step=24,
        data=F.tobytes(),
    )


def fundamental_from_image(msg: Image) -> np.ndarray:
    """Inverse of :func:`fundamental_to_image`: a 64FC1 3x3 Image -> F (3, 3) float64."""
    if msg.encoding != "64FC1" or (msg.height, msg.width) != (3, 3) or msg.step < 24:
        raise ValueError(
            f"expected a 3x3 64FC1 image, got {msg.width}x{msg.height} {msg.encoding!r}"
        )
    order = ">" if msg.is_bigendian else "<"
    raw = np.frombuffer(memoryview(msg.data).cast("B"), dtype=np.uint8)
    if raw.size < 3 * msg.step:
        raise ValueError(f"F image data too short: {raw.size} B < {3 * msg.step} B")
    rows = raw[: 3 * msg.step].reshape(3, msg.step)[:, :24]
    return rows.view(np.dtype(order + "f8")).reshape(3, 3).astype(np.float64)


def _fmt(value: Any) -> str:
    if isinstance(value, float):
        return "nan" if math.isnan(value) else f"{value:.6g}"
    return str(value)


def key_values(values: Mapping[str, Any]) -> list[KeyValue]:
    """name -> value as diagnostic_msgs/KeyValue (floats with 6 significant digits)."""
    return [KeyValue(key=str(k), value=_fmt(v)) for k, v in values.items()]


def health_status(
    name: str, level: bytes, message: str, values: Mapping[str, Any], hardware_id: str = ""
) -> DiagnosticStatus:
    """A diagnostic_msgs/DiagnosticStatus; ``level`` is DiagnosticStatus.OK/WARN/ERROR/STALE."""
    return DiagnosticStatus(
        level=level,
        name=name,
        message=message,
        hardware_id=hardware_id,
        values=key_values(values),
    )


def diagnostic_array(header: Header, statuses: list[DiagnosticStatus]) -> DiagnosticArray:
    """Wrap statuses into a diagnostic_msgs/DiagnosticArray with ``header`` (copied)."""
    return DiagnosticArray(header=copy_header(header), status=statuses)


def status_values(status: DiagnosticStatus) -> dict[str, str]:
    """The values of a DiagnosticStatus as a dict (for readers and tests)."""
    return {kv.key: kv.value for kv in status.values}
