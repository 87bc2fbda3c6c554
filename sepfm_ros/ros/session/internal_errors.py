"""How an unexpected exception of a pair is counted and logged, by the node and offline alike."""

from __future__ import annotations

import traceback


def internal_error_kind(err: BaseException) -> str:
    """The kind under which an internal error is counted in ``/diagnostics``."""
    return f"internal_{type(err).__name__}"


def internal_error_text(err: BaseException) -> str:
    """An internal error with its traceback, for the log."""
    return "".join(traceback.format_exception(err))
