"""The node's health: counters, recent-window problem tracking, input stalls and the level of its
``/diagnostics`` status. Pure Python, no ROS (the node adds the DDS graph figures and publishes).

The level comes from what happened recently (the last ``window_s`` seconds), not from lifetime
counters, so one bad message does not leave WARN latched: ERROR while an internal exception
occurred in the window, WARN while bad inputs, lost samples, frames missing from a camera's
stamp sequence (:mod:`sepfm_ros.stream.frame_gaps`), stamp jumps or an input stall did, OK
otherwise. Lifetime counters stay in the values for the record.
"""

from __future__ import annotations

import threading
import time
from collections import Counter, deque
from collections.abc import Callable, Iterable
from typing import Any

import numpy as np

from sepfm_ros.stream.frame_gaps import StampGaps

OK, WARN, ERROR = 0, 1, 2
INTERNAL_PREFIX = "internal_"  # error kinds of exceptions inside the node (ERROR level)

# How often input silence is checked (a change of the health level is reported at once).
STALL_CHECK_PERIOD_S = 0.1
# Events of one kind remembered for the recent window (bounded under a flood).
MAX_EVENTS_PER_KIND = 4096
# recent-window kinds of the stamp sequences (frames received with a known period, and missing)
_STAMPED, _MISSING = "frames_stamped", "frames_missing"


class RecentEvents:
    """Times of events per kind within the last ``window_s`` seconds (bounded per kind)."""

    def __init__(self, window_s: float) -> None:
        self.window_s = float(window_s)
        self._times: dict[str, deque[float]] = {}

    def add(self, kind: str, now: float, count: int = 1) -> None:
        """Record ``count`` events of ``kind`` at monotonic time ``now`` (s)."""
        times = self._times.setdefault(kind, deque(maxlen=MAX_EVENTS_PER_KIND))
        times.extend([now] * min(int(count), MAX_EVENTS_PER_KIND))

    def counts(self, now: float) -> dict[str, int]:
        """kind -> events within the window ending at ``now`` (kinds with none are left out)."""
        out = {}
        for kind, times in self._times.items():
            while times and now - times[0] > self.window_s:
                times.popleft()
            if times:
                out[kind] = len(times)
        return out


class LogThrottle:
    """Lets a recurring message through once per ``period_s`` per kind, with the count of those
    held back in between (so a problem that lasts is logged again, not once per process)."""

    def __init__(self, period_s: float = 10.0) -> None:
        self.period_s = float(period_s)
        self._last: dict[str, float] = {}
        self._held: Counter[str] = Counter()

    def admit(self, kind: str, now: float) -> int | None:
        """None when a message of ``kind`` at ``now`` is held back; otherwise the number held
        back since the last one let through."""
        last = self._last.get(kind)
        if last is not None and now - last < self.period_s:
            self._held[kind] += 1
            return None
        self._last[kind] = now
        held, self._held[kind] = self._held[kind], 0
        return held

    def message(self, kind: str, text: str, now: float) -> str | None:
        """``text`` as logged when a message of ``kind`` at ``now`` is let through (with the
        count held back since the last one and the throttling said), None when held back."""
        held = self.admit(kind, now)
        if held is None:
            return None
        more = f" [{held} more since the last report]" if held else ""
        note = f" [logged at most every {self.period_s:.0f} s, counted in /diagnostics]"
        return text + more + note


def percentile(values: Iterable[float], q: float) -> float:
    """q-th percentile of ``values`` (nan when empty)."""
    values = list(values)
    return float(np.percentile(values, q)) if values else float("nan")


class Health:
    """Counters and problem events of the node (thread-safe).

    Args:
        topics: the input names ("left", "right" in stereo mode; "image" in motion mode).
        input_timeout_s: a stereo camera silent this much longer than the other is a stall,
            and both cameras streaming without a pair for this long is a sync problem.
        window_s: the recent window the level is judged on, s.
        clock: monotonic time in seconds (injectable for tests).
    """

    def __init__(
        self,
        topics: tuple[str, ...],
        input_timeout_s: float,
        window_s: float = 10.0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.topics = topics
        self.input_timeout_s = float(input_timeout_s)
        self._clock = clock
        self._lock = threading.Lock()
        self._recent = RecentEvents(window_s)
        self.received: Counter[str] = Counter()
        self.errors: Counter[str] = Counter()  # lifetime, by kind
        self.lost: Counter[str] = Counter()  # samples lost in transport, by input
        self.gaps = StampGaps(pause_s=max(1.0, self.input_timeout_s))
        self.published = 0
        self.not_ok = 0
        self.stamp_jumps = 0
        self._last_input: dict[str, float] = {}
        self._last_pair: float | None = None
        self._both_since: float | None = None  # both stereo inputs streaming since
        self._stereo_offset_ns: deque[int] = deque(maxlen=15)
        self._latency_ms: deque[float] = deque(maxlen=500)
        self._max_wait_ms = 0.0
        self._last_report = (clock(), Counter(), 0)

    @property
    def window_s(self) -> float:
        return self._recent.window_s

    # ------------------------------------------------------------------ events
    def input(self, topic: str) -> float:
        """A message arrived on input ``topic``; returns its receipt time (monotonic s)."""
        now = self._clock()
        with self._lock:
            self.received[topic] += 1
            self._last_input[topic] = now
            ages = [now - t for t in self._last_input.values()]
            if len(ages) < 2 or max(ages) >= self.input_timeout_s:
                self._both_since = None  # not both inputs streaming
            elif self._both_since is None:
                self._both_since = now
        return now

    def problem(self, kind: str, count: int = 1) -> None:
        """``count`` problems of ``kind`` (a bad input, ``internal_<Exception>``, ...)."""
        with self._lock:
            self.errors[kind] += count
            self._recent.add(kind, self._clock(), count)

    def lost_samples(self, topic: str, count: int) -> None:
        """DDS reported ``count`` samples of ``topic`` lost in transport."""
        with self._lock:
            self.lost[topic] += count
            self._recent.add("lost_samples", self._clock(), count)

    def frame_stamp(self, topic: str, stamp_ns: int) -> None:
        """A valid frame of input ``topic`` stamped ``stamp_ns``: counts the frames missing
        from its stamp sequence before it."""
        with self._lock:
            missing = self.gaps.add(topic, stamp_ns)
            if self.gaps.period_s(topic) is not None:
                now = self._clock()
                self._recent.add(_STAMPED, now)
                if missing:
                    self._recent.add(_MISSING, now, missing)

    def stamp_jump(self) -> None:
        """The input stamps went back and the history was reset."""
        with self._lock:
            self.stamp_jumps += 1
            self._recent.add("stamp_jump", self._clock())

    def stereo_offset(self, offset_ns: int) -> None:
        """Right minus left stamp of the nearest recent left/right messages, ns."""
        with self._lock:
            self._stereo_offset_ns.append(int(offset_ns))

    def pair_formed(self) -> None:
        with self._lock:
            self._last_pair = self._clock()

    def answered(self, latency_ms: float, wait_ms: float, published: bool, ok: bool) -> None:
        """A pair was answered on the output topics."""
        with self._lock:
            self._latency_ms.append(latency_ms)
            self._max_wait_ms = max(self._max_wait_ms, wait_ms)
            self.published += int(published)
            self.not_ok += int(not ok)

    def restart_input(self) -> None:
        """Forget when each input last arrived and when the last pair formed (the node
        subscribed again after an idle spell: no stall is judged on the time it held none)."""
        with self._lock:
            self._last_input.clear()
            self._both_since = None
            self._last_pair = None

    def restart_pairing(self) -> None:
        """Forget when the last pair formed (the input restarted)."""
        with self._lock:
            self._last_pair = None

    # ------------------------------------------------------------------ judgement
    def _stall(self, now: float) -> str | None:
        """Why the stereo input looks stalled or unpaired, or None (lock held)."""
        if self.topics != ("left", "right"):
            return None
        last = self._last_input
        timeout = self.input_timeout_s
        ages = {topic: now - t for topic, t in last.items()}
        for topic, other in (("left", "right"), ("right", "left")):
            if topic not in ages and other in ages and ages[other] < timeout:
                if now - min(last.values()) > timeout:
                    return f"no {topic} images yet, {other} images arriving"
            if (
                topic in ages
                and other in ages
                and ages[other] < timeout
                and ages[topic] - ages[other] > timeout
            ):
                return (
                    f"{topic} camera silent for {ages[topic]:.1f} s while {other} images "
                    "arrive: no pairs"
                )
        if len(ages) == 2 and max(ages.values()) < timeout and self._both_since is not None:
            start = self._both_since
            if self._last_pair is not None:
                start = max(start, self._last_pair)
            if now - start > timeout:
                return self._unpaired_reason(now - start)
        return None

    def _unpaired_reason(self, seconds: float) -> str:
        offsets = list(self._stereo_offset_ns)
        if not offsets:
            return f"left and right images arrive but no pair formed for {seconds:.1f} s"
        offset_ms = float(np.median(offsets)) / 1e6
        need_s = abs(offset_ms) / 1e3 + 0.001
        return (
            f"left and right images arrive but no pair formed for {seconds:.1f} s: right stamps "
            f"differ from left by {offset_ms:+.1f} ms; set sync_slop_s to at least {need_s:.3f}"
            " (up to half the frame period)"
        )

    def stall(self) -> str | None:
        """Why the input looks stalled or unpaired now, or None."""
        with self._lock:
            return self._stall(self._clock())

    def level(self, stall: str | None = None) -> tuple[int, str]:
        """(OK / WARN / ERROR, message) from the recent window and the current stall."""
        with self._lock:
            recent = self._recent.counts(self._clock())
        internal = {k: n for k, n in recent.items() if k.startswith(INTERNAL_PREFIX)}
        if internal:
            kinds = ", ".join(f"{n} {k}" for k, n in sorted(internal.items()))
            return ERROR, f"internal errors in the last {self.window_s:.0f} s: {kinds}"
        if stall is not None:
            return WARN, stall
        parts = []
        stamped, missing = recent.pop(_STAMPED, 0), recent.pop(_MISSING, 0)
        lost = recent.pop("lost_samples", 0)
        jumps = recent.pop("stamp_jump", 0)
        bad = sum(recent.values())
        if bad:
            kinds = ", ".join(f"{n} {k}" for k, n in sorted(recent.items()))
            parts.append(f"{bad} bad inputs skipped ({kinds})")
        if lost:
            parts.append(
                f"{lost} input samples lost in transport (large images over best-effort QoS:"
                " publish reliable, or set input_reliability:=reliable)"
            )
        if missing:
            parts.append(
                f"{missing} of {missing + stamped} frames ({missing / (missing + stamped):.0%})"
                " missing from the camera stamp sequence: sent but not received (a link too slow"
                " for the images: image_transport:=compressed needs less), or dropped by the camera"
            )
        if jumps:
            parts.append(f"input stamps jumped back {jumps} times (history reset)")
        if parts:
            return WARN, "; ".join(parts) + f" in the last {self.window_s:.0f} s"
        return OK, "ok"

    def values(self) -> dict[str, Any]:
        """The figures of the /diagnostics report (rates over the time since the last call)."""
        now = self._clock()
        with self._lock:
            t_last, received_last, published_last = self._last_report
            dt = max(now - t_last, 1e-6)
            values: dict[str, Any] = {}
            for topic in self.topics:
                values[f"input_rate_{topic}_hz"] = (
                    self.received[topic] - received_last[topic]
                ) / dt
                values[f"received_{topic}"] = self.received[topic]
            values["output_rate_hz"] = (self.published - published_last) / dt
            values["published"] = self.published
            values["estimation_not_ok"] = self.not_ok
            lat = list(self._latency_ms)
            values["latency_p50_ms"] = percentile(lat, 50)
            values["latency_p95_ms"] = percentile(lat, 95)
            values["wait_max_ms"] = self._max_wait_ms
            values["errors_total"] = sum(self.errors.values())
            for kind, count in sorted(self.errors.items()):
                values[f"errors_{kind}"] = count
            recent = self._recent.counts(now)
            recent.pop(_STAMPED, None)
            values["problems_recent"] = sum(recent.values())
            values["frames_missing"] = sum(self.gaps.missing(t) for t in self.topics)
            for topic in self.topics:
                values[f"frames_missing_{topic}"] = self.gaps.missing(topic)
                values[f"frames_missing_share_{topic}"] = round(self.gaps.share_missing(topic), 4)
            values["lost_samples"] = sum(self.lost.values())
            for topic, count in sorted(self.lost.items()):
                values[f"lost_samples_{topic}"] = count
            values["stamp_jumps"] = self.stamp_jumps
            if self._stereo_offset_ns:
                values["stereo_offset_ms"] = float(np.median(self._stereo_offset_ns)) / 1e6
            for topic, t in self._last_input.items():
                values[f"input_age_{topic}_s"] = now - t
            self._last_report = (now, Counter(self.received), self.published)
        return values
