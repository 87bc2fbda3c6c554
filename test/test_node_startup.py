"""SIGINT / SIGTERM stop the node cleanly while it compiles its kernels (a fresh install)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_signal_during_kernel_compilation_exits_cleanly(sig, tmp_path, ros_domain_id):
    cache = tmp_path / "numba"  # an empty kernel cache: the node has to compile (tens of seconds)
    cache.mkdir()
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache))
    proc = subprocess.Popen(
        [sys.executable, "-m", "sepfm_ros", "node"],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        deadline = time.monotonic() + 120.0
        # numba makes the cache folders at import; the first file is the first compiled kernel
        while not any(p.is_file() for p in cache.rglob("*")):
            assert proc.poll() is None, proc.communicate()[0]
            assert time.monotonic() < deadline, "the node never started compiling"
            time.sleep(0.1)
        t0 = time.monotonic()
        proc.send_signal(sig)
        out, _ = proc.communicate(timeout=15)
        elapsed = time.monotonic() - t0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, out
    assert "interrupted while preparing the estimator" in out, out
    assert "Traceback" not in out, out
    assert "kernels ready" not in out, out  # it stopped without finishing the compilation
    print(f"[startup] {sig.name} during kernel compilation: exit 0 after {elapsed:.2f} s")
