"""F as message fields: the typed ``f`` field of ``sepfm_msgs`` and the ground truth image.

- :func:`fundamental_field` / :func:`fundamental_from_msg`: F as the row-major ``float64[9]``
  field of ``sepfm_msgs/TwoViewEstimate`` and back;
- :func:`fundamental_to_image` / :func:`fundamental_from_image`: a ground-truth F as a 3x3
  ``64FC1`` sensor_msgs/Image (row-major), the bags' ``/ground_truth/fundamental``.
"""

from __future__ import annotations

import sys
from typing import Any

import numpy as np
from sensor_msgs.msg import Image
from std_msgs.msg import Header

from sepfm_ros.ros.msgs.headers import copy_header


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


def fundamental_field(F: Any) -> np.ndarray:
    """F (3, 3) or (9,) -> (9,) float64, row-major and contiguous, for ``TwoViewEstimate.f``.

    Raises:
        ValueError: when F is not a 3x3 matrix or 9 values, or holds non-numbers.
    """
    try:
        arr = np.asarray(F, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"F must be a 3x3 matrix of numbers: {exc}") from None
    if arr.shape not in ((3, 3), (9,)):
        raise ValueError(f"F must have shape (3, 3) or (9,), got {arr.shape}")
    return np.ascontiguousarray(arr.reshape(9), dtype=np.float64)


def fundamental_from_msg(msg: Any) -> np.ndarray:
    """A message's ``f`` field (9 values, row-major) -> F (3, 3) float64 (a copy).

    Raises:
        ValueError: when the message's ``f`` does not hold 9 values.
    """
    arr = np.array(msg.f, dtype=np.float64)
    if arr.shape != (9,):
        raise ValueError(f"the message's f must hold 9 values, got shape {arr.shape}")
    return arr.reshape(3, 3)
