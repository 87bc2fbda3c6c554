"""Keep numba's on-disk kernel cache consistent with the package sources.

numba invalidates a cached kernel only when the kernel's own source file changes, not when a
kernel it calls (in another module) does; after an update of some modules (``git pull`` on an
editable install) a cached caller could keep running the old callee. On import, the package
compares a stamp of all its sources with the one stored beside the cache and, when they differ,
drops every cached kernel of the package so each compiles afresh once.

Several processes may import the package at once (workers of a pool, a launch file's nodes) on a
fresh or updated install. The check, the purge and the new stamp are one step under an exclusive
file lock beside the stamp, and the stamp is replaced atomically, so:

- exactly one process purges per source change; the others wait for it, then read the new stamp
  and delete nothing, in particular not the kernels the first one has started to write after its
  purge (without the lock, a process that read the old stamp just before the first one wrote the
  new stamp deleted them);
- a stamp is never seen half-written (which read as a change and purged again);
- the purge removes only finished cache files (``*.nbi``, ``*.nbc``): numba writes each one to
  a temporary name and renames it, so a file another process is writing is never touched, and a
  process whose index names a removed data file recompiles that kernel (numba's own fallback).

A read-only installation, or a system without ``fcntl`` (not Linux/macOS), keeps the unlocked
check: nothing can be purged in the first, the second is not a supported platform for ROS here.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
from collections.abc import Iterator
from pathlib import Path

try:
    import fcntl
except ImportError:  # pragma: no cover - Windows
    fcntl = None  # type: ignore[assignment]

ROOT = Path(__file__).resolve().parent
STAMP = ROOT / "__pycache__" / "numba_sources.sha256"
CACHE_PATTERNS = ("*.nbi", "*.nbc")  # numba's index and data files (finished, renamed in place)


def sources_stamp(root: Path = ROOT) -> str:
    """SHA-256 over (relative path, size, mtime) of every ``.py`` file under ``root``."""
    h = hashlib.sha256()
    for f in sorted(root.rglob("*.py")):
        st = f.stat()
        h.update(f"{f.relative_to(root)}:{st.st_size}:{st.st_mtime_ns}\n".encode())
    return h.hexdigest()


def ensure_fresh_cache(root: Path = ROOT, stamp: Path = STAMP) -> int:
    """Delete the package's cached kernels if any source changed since the stamp was written.

    Safe when several processes call it at once (see the module docstring): the first one to
    take the lock purges and writes the stamp, the others then find the stamp current.

    Returns:
        The number of cache files this call deleted (0 when the stamp matched or nothing was
        cached). A read-only installation is left as it is.
    """
    current = sources_stamp(root)
    if _read_stamp(stamp) == current:  # the stamp is replaced atomically: a match is complete
        return 0
    with _exclusive(stamp):
        if _read_stamp(stamp) == current:  # another process purged while this one waited
            return 0
        removed = _purge(root)
        _write_stamp(stamp, current)
    return removed


def _read_stamp(stamp: Path) -> str | None:
    """The stored stamp, or None when there is none (or it cannot be read)."""
    try:
        return stamp.read_text()
    except OSError:
        return None


def _write_stamp(stamp: Path, value: str) -> None:
    """Replace the stamp atomically (a temporary file renamed over it); silent when read-only."""
    tmp = stamp.with_name(f"{stamp.name}.tmp.{os.getpid()}")
    try:
        tmp.write_text(value)
        os.replace(tmp, stamp)
    except OSError:
        with contextlib.suppress(OSError):
            tmp.unlink()


def _purge(root: Path) -> int:
    """Delete the finished numba cache files under ``root``'s ``__pycache__`` folders."""
    removed = 0
    for pattern in CACHE_PATTERNS:
        for f in root.rglob(f"__pycache__/{pattern}"):
            try:
                f.unlink()
                removed += 1
            except OSError:  # gone already, or read-only
                pass
    return removed


@contextlib.contextmanager
def _exclusive(stamp: Path) -> Iterator[None]:
    """Hold an exclusive lock on ``<stamp>.lock`` (blocking) while the block runs.

    Without a lock file (read-only installation) or ``fcntl`` (Windows), the block runs
    unlocked.
    """
    lock_path = stamp.with_name(f"{stamp.name}.lock")
    try:
        stamp.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(lock_path, os.O_RDWR | os.O_CREAT, 0o666)
    except OSError:
        fd = None
    if fd is None:
        yield
        return
    try:
        if fcntl is not None:
            fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)  # closing the descriptor releases the lock
