"""Which two frames make a pair: stereo pairing by stamp, motion pairing by frame gap, and the
reset when the input's stamps jump back. Pure Python, no ROS.

A stamp that goes back by more than ``jump_back_s`` (a looped bag, a camera driver restart, a
simulator reset) starts the pairing afresh from that frame, instead of dropping every later frame
as late. A smaller step back is a reordered or repeated frame and is skipped as before. In stereo,
each camera's stamps are compared with that camera's own newest, so one topic delivered seconds
behind the other is not a jump back.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Generic, TypeVar

from sepfm_ros.stream.sync import ApproximateTimeSync

T = TypeVar("T")

NS_PER_S = 1_000_000_000


@dataclass
class Frame(Generic[T]):
    """An input frame: its item (message and receipt time) and stamp (ns)."""

    item: T
    stamp_ns: int


@dataclass
class PairOutcome(Generic[T]):
    """What one added frame did: the pair it completed (a, b), if any, and whether it reset
    the pairing (stamps jumped back) or was skipped as late (stamp not after the last)."""

    pair: tuple[Frame[T], Frame[T]] | None = None
    reset: bool = False
    late: bool = False


class StereoPairing(Generic[T]):
    """Left/right frames paired by stamp (:class:`ApproximateTimeSync`), reset on a jump back.

    A frame whose stamp is more than ``jump_back_s`` older than its own side's newest starts the
    pairing afresh. The other side's queued frames within ``jump_back_s`` of it (the new
    timeline's, which that side may have sent first) are kept; the rest are dropped, and the
    other side's newest is forgotten so that its own first frame of the new timeline is not a
    second jump back.

    Args:
        slop_ns: largest stamp difference of a pair, ns.
        queue_size: unpaired frames kept per side.
        jump_back_s: a stamp this much older than its side's newest resets the pairing, s.
    """

    def __init__(self, slop_ns: int, queue_size: int, jump_back_s: float = 1.0) -> None:
        self._sync: ApproximateTimeSync[Frame[T]] = ApproximateTimeSync(slop_ns, queue_size)
        self.jump_back_ns = int(round(jump_back_s * NS_PER_S))
        self._newest: list[int | None] = [None, None]
        self.resets = 0  #: restarts so far (a stamp of a frame is unique within one)
        self._recent: tuple[deque[int], deque[int]] = (deque(maxlen=8), deque(maxlen=8))

    @property
    def stats(self):
        return self._sync.stats

    def configure(self, slop_ns: int, queue_size: int, jump_back_s: float) -> None:
        self._sync.configure(slop_ns, queue_size)
        self.jump_back_ns = int(round(jump_back_s * NS_PER_S))

    def offset_ns(self) -> int | None:
        """Right minus left stamp of the nearest pair among the recent left and right frames
        (ns), or None: the same whichever of a frame's two images arrives first."""
        left, right = self._recent
        if not left or not right:
            return None
        return min((r - s for r in right for s in left), key=abs)

    def _restart(self, side: int, stamp_ns: int) -> None:
        """A fresh sync holding only the other side's queued frames near ``stamp_ns``."""
        other = 1 - side
        kept = [
            (s, item)
            for s, item in self._sync.queued(other)
            if abs(s - stamp_ns) <= self.jump_back_ns
        ]
        stats = self._sync.stats
        self._sync = ApproximateTimeSync(self._sync.slop_ns, self._sync.queue_size)
        self._sync.stats = stats  # counters stay lifetime counters
        self._sync.requeue(other, kept)
        self._recent[side].clear()
        self._recent[other].clear()
        self._recent[other].extend(s for s, _ in kept)
        self._newest[side] = None
        self._newest[other] = max((s for s, _ in kept), default=None)

    def add(self, side: int, frame: Frame[T]) -> PairOutcome[T]:
        """Add a frame of ``side`` (LEFT or RIGHT)."""
        out: PairOutcome[T] = PairOutcome()
        stamp = frame.stamp_ns
        newest = self._newest[side]
        if newest is not None and stamp < newest - self.jump_back_ns:
            self._restart(side, stamp)
            self.resets += 1
            out.reset = True
        newest = self._newest[side]
        self._newest[side] = stamp if newest is None else max(newest, stamp)
        self._recent[side].append(stamp)
        late_before = self._sync.stats.late
        pair = self._sync.add(side, stamp, frame)
        out.late = self._sync.stats.late > late_before
        if pair is not None:
            out.pair = pair
        return out


class MotionPairing(Generic[T]):
    """Frame t - ``frame_gap`` paired with frame t, reset on a jump back.

    Args:
        frame_gap: frames between the two of a pair (1 = consecutive).
        jump_back_s: a stamp this much older than the last frame's resets the history, s.
    """

    def __init__(self, frame_gap: int, jump_back_s: float = 1.0) -> None:
        self._history: deque[Frame[T]] = deque(maxlen=frame_gap + 1)
        self.resets = 0  #: restarts so far (a stamp of a frame is unique within one)
        self.jump_back_ns = int(round(jump_back_s * NS_PER_S))

    @property
    def frame_gap(self) -> int:
        return int(self._history.maxlen or 1) - 1

    def configure(self, frame_gap: int, jump_back_s: float) -> None:
        if frame_gap != self.frame_gap:
            self._history = deque(self._history, maxlen=frame_gap + 1)
        self.jump_back_ns = int(round(jump_back_s * NS_PER_S))

    def add(self, frame: Frame[T]) -> PairOutcome[T]:
        """Add the newest frame."""
        out: PairOutcome[T] = PairOutcome()
        if self._history:
            last = self._history[-1].stamp_ns
            if frame.stamp_ns < last - self.jump_back_ns:
                self._history.clear()
                self.resets += 1
                out.reset = True
            elif frame.stamp_ns <= last:
                out.late = True
                return out
        self._history.append(frame)
        if len(self._history) == self._history.maxlen:
            out.pair = (self._history[0], frame)
        return out


def stamp_order_effects(stamps: list[int], jump_back_s: float = 1.0) -> tuple[int, int]:
    """What the pairing does with one topic's header stamps (ns, arrival order): (frames
    skipped because their stamp is not after the topic's newest, restarts on a jump back of
    more than ``jump_back_s``): :class:`MotionPairing` run on them, which judges each side of
    :class:`StereoPairing` the same way."""
    pairing: MotionPairing[None] = MotionPairing(1, jump_back_s)
    late = sum(pairing.add(Frame(None, stamp)).late for stamp in stamps)
    return late, pairing.resets
