"""How a long-running sepfm node meets trouble and keeps serving.

- :class:`ThrottledLog`: a recurring problem is logged at most once per period per kind, with the
  count held back since the last line (the counts themselves go to ``/diagnostics``).
- :func:`internal_error_kind` and :func:`internal_error_text`: how an unexpected exception is
  counted and logged (by the callbacks below and by the sepfm node's worker threads).
- :func:`guarded`: an exception in an executor callback is counted as an internal error and
  logged through the node's :meth:`KeepsServing.internal_error`, never raised into the executor.

Both nodes (``sepfm`` and ``rectify``) use them.
"""

from __future__ import annotations

import functools
import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Protocol, TypeVar

from sepfm_ros.ros.session.internal_errors import internal_error_kind, internal_error_text
from sepfm_ros.stream.health import LogThrottle

if TYPE_CHECKING:
    from rclpy.node import Node

# A recurring problem of one kind is logged at most once per this many seconds.
LOG_THROTTLE_S = 10.0


class ThrottledLog:
    """A node's log for recurring problems: one line per kind per ``period_s``, naming how many
    were held back since the last one. Thread-safe."""

    def __init__(self, node: Node, period_s: float = LOG_THROTTLE_S) -> None:
        self._logger = node.get_logger()
        self._throttle = LogThrottle(period_s)
        self._lock = threading.Lock()

    def log(self, kind: str, text: str, error: bool = True) -> None:
        """Log ``text`` (ERROR, or WARN when ``error`` is False) unless a message of ``kind``
        was logged in the last period."""
        with self._lock:
            line = self._throttle.message(kind, text, time.monotonic())
        if line is None:
            return
        # one call site per severity: rclpy refuses another severity at the same call site
        if error:
            self._logger.error(line)
        else:
            self._logger.warning(line)


class KeepsServing(Protocol):
    """A node whose callbacks are :func:`guarded`."""

    def internal_error(self, kind: str, text: str) -> None:
        """Count an exception of ``kind`` (``internal_<ExceptionType>``) and log ``text``
        (the callback's name and the traceback)."""


_Node = TypeVar("_Node", bound=KeepsServing)


def guarded(callback: Callable[..., None]) -> Callable[..., None]:
    """An executor callback (a method of a :class:`KeepsServing` node) that never raises: an
    exception goes to the node's ``internal_error`` and the executor keeps serving."""

    @functools.wraps(callback)
    def run(self: _Node, *args: Any) -> None:
        try:
            callback(self, *args)
        except Exception as err:  # noqa: BLE001 - a long-running node keeps serving
            text = f"{callback.__name__}: " + internal_error_text(err)
            self.internal_error(internal_error_kind(err), text)

    return run
