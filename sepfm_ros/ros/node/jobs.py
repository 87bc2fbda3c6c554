"""The pairs between the sepfm node's executor and its two worker threads, and those threads."""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from std_msgs.msg import Header

if TYPE_CHECKING:  # the pipeline's modules load after the node is in the graph
    from sepfm_ros.pipeline.pipeline import MatchedPair
    from sepfm_ros.ros.session.answer import PairAnswer, PairHeaders


@dataclass
class Job:
    """A pair waiting for the worker: a = left/earlier, b = right/current."""

    msg_a: Any
    msg_b: Any
    received: float  # time.monotonic() at receipt of the newer message
    header: Header  # header of the newer image (copied to every output)
    key_a: Any
    key_b: Any

    def headers(self) -> PairHeaders:
        """The pair's output header and its images' headers."""
        from sepfm_ros.ros.session.answer import PairHeaders

        return PairHeaders(self.header, self.msg_a.header, self.msg_b.header)


@dataclass
class MatchedJob:
    """A matched pair waiting for the estimate thread, or the failure record of a pair that
    could not be matched (``failure``: published by the estimate thread too, so answers leave
    in pair order)."""

    job: Job
    matched: MatchedPair | None
    images: tuple[np.ndarray, np.ndarray] | None  # decoded a, b (for ~/debug_image)
    wait_ms: float  # receipt -> start of processing (decode)
    matched_at: float  # time.monotonic() when matching ended
    failure: PairAnswer | None = None


def start_worker(loop: Callable[[], None], name: str) -> threading.Thread:
    """Run ``loop`` on a started daemon thread called ``name``, in the OS too (``top -H``)."""

    def run() -> None:
        from sepfm_ros.pipeline.pipeline import name_native_thread

        name_native_thread()
        loop()

    thread = threading.Thread(target=run, name=name, daemon=True)
    thread.start()
    return thread
