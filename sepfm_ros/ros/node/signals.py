"""Signal handlers shared by the long-running commands (node, process, record, replay).

Kept apart from the commands so that importing one (the node) does not import the others' bag
and progress-bar modules.
"""

from __future__ import annotations

import signal
from typing import Any

#: the signals that stop a long-running command like Ctrl-C
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


def raise_keyboard_interrupt(signum: int, frame: Any) -> None:
    """A SIGINT / SIGTERM handler: stop like Ctrl-C (so outputs are closed cleanly)."""
    raise KeyboardInterrupt


class DeferredStop:
    """SIGINT / SIGTERM as a request that a loop honours at its next safe point.

    A KeyboardInterrupt raised while a compiled (numba) kernel calls back into Python surfaces
    as a SystemError with a traceback, not as a clean stop. A command whose work runs such
    kernels installs this instead: the first signal only sets :attr:`requested` and the loop
    calls :meth:`check` between units of work; a second signal raises KeyboardInterrupt at once.
    """

    def __init__(self) -> None:
        self.requested = False

    def __call__(self, signum: int, frame: Any) -> None:
        if self.requested:
            raise KeyboardInterrupt
        self.requested = True

    def check(self) -> None:
        """Raise KeyboardInterrupt when a stop was requested."""
        if self.requested:
            raise KeyboardInterrupt


def install_stop_handlers(deferred: DeferredStop | None = None) -> dict[int, Any]:
    """Make SIGINT and SIGTERM raise KeyboardInterrupt (or, with ``deferred``, request a stop
    that it raises at the next :meth:`DeferredStop.check`); returns the handlers they replaced
    (for :func:`restore_handlers`).

    SIGINT gets a handler too, not only SIGTERM: a process started in the background by a
    shell (``cmd &``) inherits SIGINT ignored, and Python then installs no handler of its own,
    so ``kill -INT`` would be ignored.
    """
    handler = raise_keyboard_interrupt if deferred is None else deferred
    return {sig: signal.signal(sig, handler) for sig in STOP_SIGNALS}


def restore_handlers(previous: dict[int, Any]) -> None:
    """Put back the handlers :func:`install_stop_handlers` replaced."""
    for sig, handler in previous.items():
        signal.signal(sig, handler)
