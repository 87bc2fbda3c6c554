"""When the node works on which pair: the latest-only slots between the input callbacks, the match
thread and the estimate thread, and the saturation policy. Pure Python, no ROS.

The executor offers pairs (:meth:`PairScheduler.offer`); the match thread takes them
(:meth:`PairScheduler.take_for_match`) and hands its matches over
(:meth:`PairScheduler.put_matched`); the estimate thread takes those
(:meth:`PairScheduler.take_for_estimate`) and reports when it is done
(:meth:`PairScheduler.estimate_done`). Nothing queues without bound: a pair still waiting when a
newer one arrives is replaced and counted as dropped, except a pair owed an answer (it arrived
while the node was idle, or while the node keeps up and the match thread was idle), which is never
replaced. The decisions are the pure methods :meth:`PairScheduler.match_decision` and
:meth:`PairScheduler.offer`, so they can be tested with an injected clock; the blocking methods
only wait on a condition for them. The reasons behind the policy are in docs/design.md.
"""

from __future__ import annotations

import statistics
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Generic, TypeVar

# While the node keeps up, the match thread starts this much before the estimator is expected to
# finish; it never waits longer than MAX_MATCH_DELAY_S at a time (see PairScheduler).
MATCH_START_MARGIN_S = 0.004
MAX_MATCH_DELAY_S = 0.05
# While saturated (see fresher_pair_wait): a pair is fresh enough to start on when its age is at
# most this share of the input period; otherwise the next pair is awaited until it is due plus
# this share of the period (its arrival jitters), and the stale pair is taken if none comes.
FRESH_AGE_SHARE = 0.25
FRESHER_WAIT_SLACK_SHARE = 0.5

J = TypeVar("J")  # a pair offered by the input side (the node's Job)
M = TypeVar("M")  # a matched pair handed to the estimate thread


class RecentMedian:
    """Median of a stage's last few durations (seconds): robust to one slow pair."""

    def __init__(self, size: int = 9, warmup: int = 3) -> None:
        self._values: deque[float] = deque(maxlen=size)
        self._warmup = warmup
        self.value = 0.0

    @property
    def ready(self) -> bool:
        return len(self._values) >= self._warmup

    def add(self, seconds: float) -> None:
        self._values.append(seconds)
        self.value = statistics.median(self._values)


class RecentPeriod:
    """Mean time between the last few events (seconds): the input period. A mean over a span,
    not a median of intervals, so that pairs delivered in bursts (two at once after a transport
    delay) do not pass for a fast input."""

    def __init__(self, size: int = 9, warmup: int = 4) -> None:
        self._times: deque[float] = deque(maxlen=size)
        self._warmup = warmup
        self.value = 0.0

    @property
    def ready(self) -> bool:
        return len(self._times) >= self._warmup

    def add(self, t: float) -> None:
        """Record an event at monotonic time ``t`` (s)."""
        self._times.append(t)
        if len(self._times) > 1:
            self.value = (self._times[-1] - self._times[0]) / (len(self._times) - 1)

    def clear(self) -> None:
        """Forget the events (the input restarted)."""
        self._times.clear()
        self.value = 0.0


def is_saturated(period_s: float, processing_s: float) -> bool:
    """True when pairs arrive faster than the node processes them one after the other.

    Args:
        period_s: recent mean time between input pairs, s.
        processing_s: recent median time of a pair's matching plus estimation, s.
    """
    return period_s < processing_s


def fresher_pair_wait(age_s: float, period_s: float) -> float:
    """Seconds to wait for the next input pair instead of starting on a pair ``age_s`` old.

    For a saturated node (pairs are dropped anyway): a pair at most FRESH_AGE_SHARE of the
    input period ``period_s`` old is taken at once (0.0); an older one is passed over until the
    next pair is due, plus FRESHER_WAIT_SLACK_SHARE of a period for its arrival jitter. The
    latency of an answer counts from the receipt of its pair, so an answer to the next pair
    comes out at about the same time as one to the stale pair would, but a period fresher.
    """
    if age_s <= FRESH_AGE_SHARE * period_s:
        return 0.0
    return max(period_s - age_s, 0.0) + FRESHER_WAIT_SLACK_SHARE * period_s


@dataclass
class Offered(Generic[J]):
    """A pair in a slot with its receipt time (monotonic s)."""

    job: J
    received: float


class PairScheduler(Generic[J, M]):
    """The latest-only slots between input, match thread and estimate thread (thread-safe).

    Args:
        clock: monotonic time in seconds (injectable for tests).
    """

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        self._clock = clock
        self._cond = threading.Condition()
        self._slot: Offered[J] | None = None  # newest pair, waiting for the match thread
        self._owed: Offered[J] | None = None  # arrived while the match thread was idle
        self._match_idle = False  # the match thread waits for input (no pair pending)
        self._matched: M | None = None  # matched pair, waiting for the estimate thread
        self._estimating_since: float | None = None  # start of the current estimate
        self._passed_over: Offered[J] | None = None  # kept waiting for a fresher one, once
        self._stop = False
        self.match_s = RecentMedian()  # seconds per stage
        self.estimate_s = RecentMedian()
        self.period_s = RecentPeriod()  # seconds between offered pairs (the input period)
        self.offered = 0  # pairs offered (lifetime)
        self.dropped = 0  # pairs replaced in the slot before the match thread took them

    # ------------------------------------------------------------------ input side
    def offer(self, job: J, received: float) -> bool:
        """Offer a pair received at monotonic time ``received`` (s); True when it replaced (and
        so dropped) a pair that was still waiting."""
        with self._cond:
            self.period_s.add(received)
            item = Offered(job, received)
            node_idle = self._estimating_since is None
            dropped = False
            if self._match_idle and self._owed is None and (node_idle or not self.saturated()):
                self._owed = item  # answered even if newer pairs arrive before it is taken
                self._match_idle = False
            else:
                if self._slot is not None:
                    self.dropped += 1
                    dropped = True
                self._slot = item
            self.offered += 1
            self._cond.notify_all()  # both worker threads wait on this condition
            return dropped

    def reset_input(self) -> None:
        """Forget the input period (after the input restarted, e.g. its stamps jumped back)."""
        with self._cond:
            self.period_s.clear()

    # ------------------------------------------------------------------ policy (lock held)
    def saturated(self) -> bool:
        """:func:`is_saturated` on the recent timings (False until they are known)."""
        if not (self.period_s.ready and self.match_s.ready and self.estimate_s.ready):
            return False
        return is_saturated(self.period_s.value, self.match_s.value + self.estimate_s.value)

    def _match_start_delay(self, now: float) -> float:
        """Seconds the match thread should still wait before taking the newest pair (<= 0: go).

        Saturated: not before the estimator is done (it notifies), so that a pair's two stages
        never compete for the cores. Keeping up (a pair came while the previous one is being
        estimated): the match thread starts a margin before the estimator's expected end
        (running median of its duration), so that the estimator does not wait for it and the
        two overlap only briefly.
        """
        if self._estimating_since is None:
            return 0.0
        if self.saturated():
            return MAX_MATCH_DELAY_S
        if not self.estimate_s.ready:
            return 0.0
        remaining = self.estimate_s.value - (now - self._estimating_since)
        return min(remaining - MATCH_START_MARGIN_S, MAX_MATCH_DELAY_S)

    def _fresher_pair_delay(self, now: float) -> float:
        """Seconds to wait for a pair newer than the one in the slot (<= 0: take this one).

        Only while saturated (:func:`fresher_pair_wait`; at a rate the node keeps up with, every
        pair is answered, even one that waited behind a slow pair). A pair is passed over once:
        if no newer one comes, it is processed after the wait.
        """
        item = self._slot
        if item is None or item is self._passed_over or not self.saturated():
            return 0.0
        wait = fresher_pair_wait(now - item.received, self.period_s.value)
        if wait > 0.0:
            self._passed_over = item
        return wait

    def match_decision(self, now: float) -> tuple[Offered[J] | None, float | None]:
        """What the match thread does now: ``(pair, None)`` take that pair (it leaves its slot);
        ``(None, seconds)`` wait at most that long; ``(None, None)`` wait for a notification.
        Caller holds the lock (the blocking :meth:`take_for_match` does)."""
        pending = self._owed is not None or self._slot is not None
        if not pending or self._matched is not None:
            self._match_idle = not pending
            return None, None
        self._match_idle = False
        delay = self._match_start_delay(now)
        if delay <= 0.0 and self._owed is None:
            delay = self._fresher_pair_delay(now)
        if delay > 0.0:
            return None, delay
        if self._owed is not None:
            item, self._owed = self._owed, None
        else:
            item, self._slot = self._slot, None
        return item, None

    # ------------------------------------------------------------------ worker side
    def take_for_match(self) -> Offered[J] | None:
        """Block until the match thread should start on a pair; None once stopped."""
        with self._cond:
            while not self._stop:
                item, wait = self.match_decision(self._clock())
                if item is not None:
                    return item
                self._cond.wait(timeout=wait)  # a newer pair may arrive meanwhile
            return None

    def put_matched(self, matched: M, match_seconds: float) -> None:
        """Hand a matched pair to the estimate thread (replacing none: the match thread waits
        while the hand-over slot is full)."""
        with self._cond:
            self.match_s.add(match_seconds)
            self._matched = matched
            self._cond.notify_all()

    def take_for_estimate(self) -> tuple[M, float] | None:
        """Block until a matched pair is there; returns it with its start time, None once
        stopped."""
        with self._cond:
            while self._matched is None and not self._stop:
                self._cond.wait()
            if self._stop:
                return None
            matched, self._matched = self._matched, None
            self._estimating_since = t0 = self._clock()
            self._cond.notify_all()  # the match thread may prepare the next pair now
            return matched, t0

    def estimate_done(self, started: float) -> None:
        """The estimate thread finished the pair it started at ``started`` (monotonic s)."""
        with self._cond:
            self.estimate_s.add(self._clock() - started)
            self._estimating_since = None
            self._cond.notify_all()

    def stop(self) -> None:
        """Wake and stop both worker threads."""
        with self._cond:
            self._stop = True
            self._cond.notify_all()

    def snapshot(self) -> dict[str, float | int | bool]:
        """Counters and state for the health report."""
        with self._cond:
            return {
                "synchronized_pairs": self.offered,
                "dropped_pairs": self.dropped,
                "saturated": self.saturated(),
            }
