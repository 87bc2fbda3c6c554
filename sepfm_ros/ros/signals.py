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


def install_stop_handlers() -> dict[int, Any]:
    """Make SIGINT and SIGTERM raise KeyboardInterrupt; returns the handlers they replaced
    (for :func:`restore_handlers`).

    SIGINT gets a handler too, not only SIGTERM: a process started in the background by a
    shell (``cmd &``) inherits SIGINT ignored, and Python then installs no handler of its own,
    so ``kill -INT`` would be ignored.
    """
    return {sig: signal.signal(sig, raise_keyboard_interrupt) for sig in STOP_SIGNALS}


def restore_handlers(previous: dict[int, Any]) -> None:
    """Put back the handlers :func:`install_stop_handlers` replaced."""
    for sig, handler in previous.items():
        signal.signal(sig, handler)
