"""Frames missing from a camera's stamp sequence (no ROS).

A camera stamps its frames one period apart. When the stamps a node receives skip k periods,
k - 1 frames were published (or should have been) but never arrived: dropped by the camera
driver, by a link too slow for them, or by DDS. DDS reports only some of these losses (a
best-effort reader's ``message_lost`` event), and none when a reliable writer's keep-last
history replaced frames the link had not carried yet, so the stamps are the measure.

The period is estimated from the stamps alone, as the largest interval of which the recent
intervals are all near-integer multiples (so it holds even when most frames are missing, when
no two consecutive frames arrive: intervals of 3 and 4 periods give the period). Gaps longer
than ``pause_s`` are a pause of the camera, not missing frames; a stamp going back (a looped
bag, a restarted driver) restarts the estimate.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

INTERVALS_KEPT = 30  # recent intervals the period is estimated from
MIN_INTERVALS = 4  # intervals needed before gaps are counted
MAX_DIVISOR = 10  # the period is at least the smallest interval / MAX_DIVISOR
TOLERANCE = 0.2  # an interval fits the period when within this share of a period of a multiple
FIT_SHARE = 0.9  # share of the recent intervals that must fit the period


def estimate_period_ns(intervals: list[int]) -> int | None:
    """The camera period (ns) of which the intervals ``intervals`` (ns, > 0) are near-integer
    multiples: the smallest interval divided by the smallest n (1..MAX_DIVISOR) for which at
    least FIT_SHARE of them fit within TOLERANCE; None when fewer than MIN_INTERVALS or none
    fits."""
    if len(intervals) < MIN_INTERVALS:
        return None
    smallest = min(intervals)
    for n in range(1, MAX_DIVISOR + 1):
        period = smallest / n
        fits = sum(abs(i / period - round(i / period)) <= TOLERANCE for i in intervals)
        if fits >= FIT_SHARE * len(intervals):
            return int(round(period))
    return None


@dataclass
class _Input:
    last_ns: int | None = None
    intervals: deque[int] = field(default_factory=lambda: deque(maxlen=INTERVALS_KEPT))
    received: int = 0  # frames received since the period was known
    missing: int = 0


class StampGaps:
    """Counts the frames missing from each input's stamp sequence (see the module docstring).

    Args:
        pause_s: a gap longer than this is a pause (not counted), s.
    """

    def __init__(self, pause_s: float = 1.0) -> None:
        self.pause_ns = int(pause_s * 1e9)
        self._inputs: dict[str, _Input] = {}

    def add(self, topic: str, stamp_ns: int) -> int:
        """A frame of ``topic`` stamped ``stamp_ns`` arrived; returns the frames missing just
        before it (0 while the period is not known yet)."""
        state = self._inputs.setdefault(topic, _Input())
        last, state.last_ns = state.last_ns, stamp_ns
        if last is None:
            return 0
        dt = stamp_ns - last
        if dt < 0:  # stamps went back: a new sequence
            state.intervals.clear()
            return 0
        if dt == 0 or dt > self.pause_ns:
            return 0
        period = estimate_period_ns(list(state.intervals))
        state.intervals.append(dt)
        if period is None:
            return 0
        state.received += 1
        missing = max(0, int(round(dt / period)) - 1)
        state.missing += missing
        return missing

    def missing(self, topic: str) -> int:
        """Frames of ``topic`` missing so far."""
        state = self._inputs.get(topic)
        return 0 if state is None else state.missing

    def period_s(self, topic: str) -> float | None:
        """The estimated camera period of ``topic``, s (None while unknown)."""
        state = self._inputs.get(topic)
        period = None if state is None else estimate_period_ns(list(state.intervals))
        return None if period is None else period / 1e9

    def share_missing(self, topic: str) -> float:
        """Missing / (missing + received) of ``topic`` since its period was known (0 without
        any)."""
        state = self._inputs.get(topic)
        if state is None or state.received + state.missing == 0:
            return 0.0
        return state.missing / (state.received + state.missing)
