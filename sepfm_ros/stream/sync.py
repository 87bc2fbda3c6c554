"""Approximate-time pairing of two streams (left/right) by time stamp. Pure Python, no ROS.

message_filters is not available from PyPI, so this is the stereo node's pairing policy:

- Each side keeps a bounded queue (``queue_size``) of messages not yet paired, oldest evicted.
- A new message is paired at once with the message of the other side whose stamp is nearest to
  its own, if that distance is at most ``slop_ns`` (``slop_ns = 0``: exact stamps only).
  Because every arrival is matched as soon as possible, no two queued messages are ever within
  the slop of each other, so pairing on arrival is the same as pairing the closest waiting pair.
- When a pair is emitted, every queued message older than it (on either side) can no longer be
  paired in order: they are discarded and counted as ``unmatched``. Messages arriving with a
  stamp at or before the last emitted pair (reordered too late) are discarded as ``late``.
- Emitted pairs therefore have strictly increasing stamps on both sides, each message is used at
  most once, and memory is bounded by ``2 x queue_size`` messages.

Stamps are integer nanoseconds (``sec * 10**9 + nanosec``, converted by the ROS adapters:
:func:`sepfm_ros.ros.msgs.headers.stamp_ns`) to keep comparisons exact.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Generic, TypeVar

T = TypeVar("T")

LEFT, RIGHT = 0, 1


@dataclass
class SyncStats:
    """Counters of the pairing policy (monotonic)."""

    received: tuple[int, int] = (0, 0)
    pairs: int = 0
    unmatched: int = 0  # discarded because a newer pair was emitted before they found a partner
    evicted: int = 0  # pushed out of a full queue
    late: int = 0  # arrived with a stamp at or before the last emitted pair


class ApproximateTimeSync(Generic[T]):
    """Pairs items from two sides whose stamps differ by at most ``slop_ns``.

    Usage::

        sync = ApproximateTimeSync(slop_ns=5_000_000, queue_size=10)
        pair = sync.add(LEFT, stamp_ns, item)   # -> (left_item, right_item) or None
    """

    def __init__(self, slop_ns: int = 5_000_000, queue_size: int = 10) -> None:
        self._queues: tuple[deque[tuple[int, T]], deque[tuple[int, T]]] = (deque(), deque())
        self._last: tuple[int, int] | None = None
        self.stats = SyncStats()
        self.configure(slop_ns, queue_size)

    def configure(self, slop_ns: int, queue_size: int) -> None:
        """Change slop (ns, >= 0) and queue size (>= 1); queued items beyond the size go."""
        if slop_ns < 0:
            raise ValueError(f"slop must be >= 0 ns, got {slop_ns}")
        if queue_size < 1:
            raise ValueError(f"queue_size must be >= 1, got {queue_size}")
        self.slop_ns = int(slop_ns)
        self.queue_size = int(queue_size)
        for q in self._queues:
            while len(q) > self.queue_size:
                q.popleft()
                self.stats.evicted += 1

    def pending(self, side: int) -> int:
        """Number of queued, unpaired items of ``side``."""
        return len(self._queues[side])

    def queued(self, side: int) -> list[tuple[int, T]]:
        """The queued, unpaired (stamp ns, item) of ``side``, oldest first."""
        return list(self._queues[side])

    def requeue(self, side: int, entries: list[tuple[int, T]]) -> None:
        """Queue (stamp ns, item) entries of ``side`` again, as unpaired (not counted as
        received): a restarted pairing keeps the frames it has not used yet."""
        q = self._queues[side]
        q.extend(sorted(entries, key=lambda e: e[0]))
        while len(q) > self.queue_size:
            q.popleft()
            self.stats.evicted += 1

    def add(self, side: int, stamp_ns: int, item: T) -> tuple[T, T] | None:
        """Add an item of ``side`` (LEFT or RIGHT); return the (left, right) pair it completes."""
        if side not in (LEFT, RIGHT):
            raise ValueError(f"side must be LEFT (0) or RIGHT (1), got {side}")
        received = list(self.stats.received)
        received[side] += 1
        self.stats.received = (received[0], received[1])
        if self._last is not None and stamp_ns <= self._last[side]:
            self.stats.late += 1
            return None
        other = self._queues[1 - side]
        best_i, best_dt = -1, None
        for i, (s, _) in enumerate(other):
            dt = abs(s - stamp_ns)
            if dt <= self.slop_ns and (best_dt is None or dt < best_dt):
                best_i, best_dt = i, dt
        if best_i < 0:
            q = self._queues[side]
            q.append((stamp_ns, item))
            # keep the queue ordered by stamp (reordered arrivals insert in place)
            if len(q) > 1 and q[-2][0] > stamp_ns:
                ordered = sorted(q, key=lambda e: e[0])
                q.clear()
                q.extend(ordered)
            while len(q) > self.queue_size:
                q.popleft()
                self.stats.evicted += 1
            return None
        other_stamp, other_item = other[best_i]
        stamps = [0, 0]
        stamps[side], stamps[1 - side] = stamp_ns, other_stamp
        self._last = (stamps[0], stamps[1])
        # discard everything at or before the pair on both sides (cannot be paired in order)
        for s_idx, q in enumerate(self._queues):
            keep = [(s, it) for s, it in q if s > self._last[s_idx]]
            self.stats.unmatched += len(q) - len(keep) - (1 if s_idx == 1 - side else 0)
            q.clear()
            q.extend(keep)
        self.stats.pairs += 1
        if side == LEFT:
            return item, other_item
        return other_item, item
