"""Keep numba's on-disk kernel cache consistent with the package sources.

numba invalidates a cached kernel only when the kernel's own source file changes, not when a
kernel it calls (in another module) does; after an update of some modules (``git pull`` on an
editable install) a cached caller could keep running the old callee. On import, the package
compares a stamp of all its sources with the one stored beside the cache and, when they differ,
drops every cached kernel of the package so each compiles afresh once.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

ROOT = Path(__file__).resolve().parent
STAMP = ROOT / "__pycache__" / "numba_sources.sha256"


def sources_stamp(root: Path = ROOT) -> str:
    """SHA-256 over (relative path, size, mtime) of every ``.py`` file under ``root``."""
    h = hashlib.sha256()
    for f in sorted(root.rglob("*.py")):
        st = f.stat()
        h.update(f"{f.relative_to(root)}:{st.st_size}:{st.st_mtime_ns}\n".encode())
    return h.hexdigest()


def ensure_fresh_cache(root: Path = ROOT, stamp: Path = STAMP) -> int:
    """Delete the package's cached kernels if any source changed since the stamp was written.

    Returns:
        The number of cache files deleted (0 when the stamp matched or nothing was cached).
        A read-only installation is left as it is.
    """
    current = sources_stamp(root)
    try:
        if stamp.read_text() == current:
            return 0
    except OSError:
        pass
    removed = 0
    for pattern in ("*.nbi", "*.nbc"):
        for f in root.rglob(f"__pycache__/{pattern}"):
            try:
                f.unlink()
                removed += 1
            except OSError:
                pass
    try:
        stamp.parent.mkdir(exist_ok=True)
        stamp.write_text(current)
    except OSError:
        pass
    return removed
