"""Long bags split into time slices whose answers equal the unsliced run's.

A slice owns the pairs completed (by the log time of their second message) in [t0, t1). What a
pair's answer depends on besides its own two images is carried across a slice boundary by
state: the stereo pairing's queues (``sync_queue_size`` frames per side), motion's last
``frame_gap`` frames, the calibration check's sliding window of ``calibration_window``
pairs and the correction's window of ``correction_window`` pairs. So a slice reads from
``read_from = t0 - overlap``, where the overlap holds that many frames with margin, pairs those
frames as the unsliced run does, and runs the answer path on the last pairs before t0 that the
longer of the two windows holds, to fill them (their answers are dropped; the slice before owns
them). Pairs earlier than that are only paired, not estimated.
The equality is tested (``test/fleet/test_audit.py``).
"""

from __future__ import annotations

import math
from typing import Any

# frames of margin beyond what the pairing and the window hold (a lost or late frame)
MARGIN_FRAMES = 3
# the overlap is this many times the frames it must hold, for irregular frame periods
PERIOD_SLACK = 1.5


def warm_pairs(params: dict[str, Any]) -> int:
    """Pairs a slice runs the answer path on before t0: the longer of the calibration check's
    window and the correction's."""
    return max(int(params["calibration_window"]), int(params.get("correction_window", 0)))


def overlap_ns(params: dict[str, Any], period_ns: int, slop_ns: int | None) -> int:
    """How long before t0 a slice starts reading, ns: the window's pairs, the pairing's
    queue (stereo) or frame gap (motion), and a margin, at ``period_ns`` per frame."""
    frames = (
        warm_pairs(params)
        + int(params["sync_queue_size"])
        + int(params["frame_gap"])
        + MARGIN_FRAMES
    )
    return int(math.ceil(frames * max(period_ns, 1) * PERIOD_SLACK)) + int(slop_ns or 0)


def plan_slices(start_ns: int, end_ns: int, slice_s: float) -> list[tuple[int, int]]:
    """[t0, t1) log-time slices covering the bag (``slice_s`` <= 0: one slice).

    The first slice starts before any message and the last ends after every message, so
    every pair is owned by exactly one slice. Slices are of equal length, at most ``slice_s``.
    """
    lo, hi = -(2**62), 2**62
    span = end_ns - start_ns
    if slice_s <= 0 or span <= slice_s * 1e9:
        return [(lo, hi)]
    n = int(math.ceil(span / (slice_s * 1e9)))
    cuts = [start_ns + (span * k) // n for k in range(1, n)]
    bounds = [lo, *cuts, hi]
    return list(zip(bounds[:-1], bounds[1:], strict=True))
