"""Starting the package's commands as a shell would, for the tests that run them as
subprocesses."""

from __future__ import annotations

import signal


def as_background_job() -> None:
    """``preexec_fn`` for a subprocess started the way a shell starts a background job
    (``cmd &`` without job control): SIGINT ignored, which the command inherits."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
