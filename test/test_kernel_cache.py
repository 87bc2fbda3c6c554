"""The numba cache is dropped when any package source changes (stale cross-module kernels)."""

from __future__ import annotations

import os

from sepfm_ros.kernel_cache import ensure_fresh_cache


def test_cache_dropped_only_when_a_source_changes(tmp_path):
    pkg = tmp_path / "pkg"
    (pkg / "sub" / "__pycache__").mkdir(parents=True)
    (pkg / "a.py").write_text("x = 1\n")
    (pkg / "sub" / "b.py").write_text("y = 2\n")
    stamp = pkg / "__pycache__" / "stamp"
    cached = [
        pkg / "sub" / "__pycache__" / "b.f-1.py311.nbi",
        pkg / "sub" / "__pycache__" / "b.f-1.py311.1.nbc",
    ]

    def cache():
        for f in cached:
            f.write_bytes(b"kernel")

    cache()
    assert ensure_fresh_cache(pkg, stamp) == 2  # no stamp yet: unknown provenance, dropped
    cache()
    assert ensure_fresh_cache(pkg, stamp) == 0  # nothing changed: kept
    assert all(f.exists() for f in cached)
    (pkg / "a.py").write_text("x = 10\n")  # a *different* module changes (a callee, say)
    assert ensure_fresh_cache(pkg, stamp) == 2
    assert not any(f.exists() for f in cached)
    cache()
    st = (pkg / "sub" / "b.py").stat()
    os.utime(pkg / "sub" / "b.py", ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))  # touched
    assert ensure_fresh_cache(pkg, stamp) == 2
