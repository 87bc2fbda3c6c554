"""The numba cache is dropped when any package source changes (stale cross-module kernels)."""

from __future__ import annotations

import os
import re
import subprocess
import sys

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


def test_warm_up_compiles_once_then_loads_from_the_cache(tmp_path):
    # a cache of its own (NUMBA_CACHE_DIR takes precedence over the in-tree one): the first run
    # must compile, the second must only load, and both say where the cache is
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba"))
    cmd = [sys.executable, "-m", "sepfm_ros", "warm_up"]
    runs = []
    for _ in range(2):
        r = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=900)
        assert r.returncode == 0, r.stdout + r.stderr
        assert f"cache: {tmp_path / 'numba'}" in r.stdout, r.stdout
        runs.append(r.stdout)
    first = re.search(r"compiled (\d+) kernels and loaded (\d+) from the cache in", runs[0])
    assert first and int(first.group(1)) >= 10, runs[0]
    second = re.search(r"loaded all (\d+) kernels from the cache \(nothing to compile\)", runs[1])
    assert second and int(second.group(1)) >= 10, runs[1]
    assert any((tmp_path / "numba").rglob("*.nbi"))
