"""The one way to put F into, and take it out of, a ``sepfm_msgs/TwoViewEstimate``.

The generated Python setter of a ``float64[9]`` field accepts a (3, 3) numpy array without
complaint and then serialises garbage (it copies the array's buffer, not its rows): every F goes
into the message through :func:`fundamental_field` and comes out through
:func:`fundamental_from_msg`.
"""

from __future__ import annotations

from typing import Any

import numpy as np


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
