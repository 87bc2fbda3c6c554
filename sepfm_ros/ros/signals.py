"""Signal handlers shared by the long-running commands (node, process, record, replay).

Kept apart from the commands so that importing one (the node) does not import the others' bag
and progress-bar modules.
"""

from __future__ import annotations

from typing import Any


def raise_keyboard_interrupt(signum: int, frame: Any) -> None:
    """A SIGTERM handler: stop like Ctrl-C (so outputs are closed cleanly)."""
    raise KeyboardInterrupt
