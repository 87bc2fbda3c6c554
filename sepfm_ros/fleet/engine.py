"""The audit's engine: Dask distributed, started in-process on this machine's cores by default,
or an existing cluster joined by its scheduler address.

Dask over Ray (docs/design.md, figures in docs/benchmarks.md): on this project's scale (tasks of
seconds, a few to hundreds of workers) both are far faster than the work; Dask starts in about
a second without daemons, its worker costs less memory, it installs in a sixth of Ray's size,
and a cluster is two plain commands (``dask scheduler``, ``dask worker ADDRESS``).

A worker process that dies while it runs a task (killed, out of memory) is replaced by its
nanny and the scheduler runs the task again elsewhere, up to
``distributed.scheduler.allowed-failures`` times (then the result raises ``KilledWorker``).
So a task's result may be computed more than once; the tasks write nothing, the driver writes.
"""

from __future__ import annotations

import logging
import os
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

ENGINE_MISSING = (
    "the audit runs on Dask distributed, which is not installed: "
    "pip install 'sepfm_ros[fleet]' (or pip install distributed)"
)


class EngineError(RuntimeError):
    """The engine is missing or the cluster cannot be reached (a message for people)."""


def default_workers() -> int:
    """Worker processes of a local run: one per core."""
    return max(1, os.cpu_count() or 1)


@contextmanager
def engine(address: str | None, workers: int | None = None) -> Iterator[Any]:
    """A ``distributed.Client``: on a local cluster of ``workers`` single-threaded worker
    processes (default one per core), or on the cluster at ``address``.

    Raises:
        EngineError: distributed is not installed, or the scheduler cannot be reached.
    """
    try:
        from distributed import Client, LocalCluster
    except ImportError:
        raise EngineError(ENGINE_MISSING) from None
    if address is not None:
        try:
            client = Client(address, timeout="20s")
        except (OSError, TimeoutError) as err:
            raise EngineError(f"cannot reach the Dask scheduler at {address}: {err}") from None
        try:
            yield client
        finally:
            client.close()
        return
    with warnings.catch_warnings():
        # the scheduler's HTTP server (health, metrics) moves to a free port when another
        # cluster holds the default one: nothing the user must act on
        warnings.filterwarnings("ignore", message="Port .* is already in use", category=UserWarning)
        cluster = LocalCluster(
            n_workers=workers or default_workers(),
            threads_per_worker=1,
            processes=True,
            dashboard_address=None,
            silence_logs=logging.ERROR,
        )
    client = Client(cluster)
    try:
        yield client
    finally:
        client.close()
        cluster.close()


def submit(client: Any, fn: Callable[..., Any], *args: Any, key: str) -> Any:
    """Submit one task (never cached by value: the same bag audited again runs again)."""
    return client.submit(fn, *args, key=key, pure=False)


def outcome(future: Any) -> tuple[Any, str | None]:
    """(result, None), or (None, reason) when the task itself failed (a worker died on it too
    often, or it raised): the reason names the failure for the bag's row."""
    try:
        return future.result(), None
    except Exception as err:  # noqa: BLE001 - KilledWorker, a worker's exception, ...
        name = type(err).__name__
        if name == "KilledWorker":
            return None, f"a worker died on every try of this bag's task ({err})"
        return None, f"task failed: {name}: {err}"


def worker_pids(client: Any) -> dict[str, int]:
    """Worker address -> process id (for tests and measurements)."""
    return client.run(os.getpid)
