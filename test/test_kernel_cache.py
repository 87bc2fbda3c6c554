"""The numba cache is dropped when any package source changes (stale cross-module kernels), and
processes that start at once never delete each other's freshly written kernels."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import textwrap
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from sepfm_ros import kernel_cache
from sepfm_ros.kernel_cache import ensure_fresh_cache

REPO = Path(__file__).resolve().parent.parent


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


def _wait_for(condition: Callable[[], bool], what: str, timeout_s: float = 300.0) -> None:
    """Poll ``condition`` until it holds; fail naming ``what`` after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.01)


def _blocked_on_lock(pid: int, lock: Path) -> bool:
    """Whether process ``pid`` waits for a lock on ``lock`` (Linux: the ``->`` rows of
    /proc/locks are blocked requests; a row names the pid and dev:inode of the file)."""
    inode = f":{os.stat(lock).st_ino} "
    rows = Path("/proc/locks").read_text().splitlines()
    return any("->" in row and f" {pid} " in row and inode in row for row in rows)


# A worker's check, loaded from the file alone (importing the package would run its own check).
# ``pause`` pauses it at its first deletion of a cache file until ``go`` exists: a process
# descheduled (or on a slow shared file system) between deciding to purge and purging.
CHECK = textwrap.dedent(
    """
    import importlib.util, os, sys, time
    from pathlib import Path

    source, pkg, stamp, mode, paused, go = sys.argv[1:7]
    spec = importlib.util.spec_from_file_location("kernel_cache_under_test", source)
    kc = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(kc)
    if mode == "pause":
        unlink = Path.unlink

        def paused_unlink(self, *args, **kwargs):
            if self.suffix in (".nbi", ".nbc") and not Path(paused).exists():
                Path(paused).touch()
                while not Path(go).exists():
                    time.sleep(0.01)
            return unlink(self, *args, **kwargs)

        Path.unlink = paused_unlink
    removed = kc.ensure_fresh_cache(Path(pkg), Path(stamp))
    if mode == "write":
        # what a numba worker does after the check: write its kernels, each under a temporary
        # name renamed in place
        for name in ("a.g-9.py311.nbi", "a.g-9.py311.1.nbc"):
            final = Path(pkg) / "__pycache__" / name
            tmp = final.with_name(name + ".tmp.1")
            tmp.write_bytes(b"fresh kernel")
            os.replace(tmp, final)
    print(removed)
    """
)


@pytest.mark.skipif(not Path("/proc/locks").exists(), reason="needs Linux's /proc/locks")
def test_a_worker_paused_in_its_purge_never_deletes_kernels_written_after_it(tmp_path):
    # An updated install: a stale kernel and the previous version's stamp. Worker B decides to
    # purge and is paused before deleting; worker A starts meanwhile, checks and writes its
    # kernels; then B resumes. A's kernels must survive, and exactly one worker purges. (Before
    # the lock, A read the old stamp too, purged, wrote; B resumed and deleted A's kernels.)
    pkg = tmp_path / "pkg"
    (pkg / "__pycache__").mkdir(parents=True)
    (pkg / "a.py").write_text("x = 1\n")
    stale = [pkg / "__pycache__" / n for n in ("a.f-1.py311.nbi", "a.f-1.py311.1.nbc")]
    for f in stale:
        f.write_bytes(b"stale kernel")
    stamp = pkg / "__pycache__" / "stamp"
    stamp.write_text("previous version")
    paused, go = tmp_path / "paused", tmp_path / "go"

    def worker(mode: str) -> subprocess.Popen:
        args = [kernel_cache.__file__, pkg, stamp, mode, paused, go]
        return subprocess.Popen(
            [sys.executable, "-c", CHECK, *map(str, args)], stdout=subprocess.PIPE, text=True
        )

    b = worker("pause")
    try:
        _wait_for(lambda: paused.exists() or b.poll() is not None, "worker B to start purging")
        assert b.poll() is None, "worker B ended before purging"
        a = worker("write")
        try:
            lock = stamp.with_name(stamp.name + ".lock")
            _wait_for(
                lambda: a.poll() is not None or (lock.exists() and _blocked_on_lock(a.pid, lock)),
                "worker A to finish or wait for the lock",
            )
            go.touch()
            out_a, _ = a.communicate(timeout=300)
        finally:
            a.kill()
        out_b, _ = b.communicate(timeout=300)
    finally:
        go.touch()
        b.kill()
    assert a.returncode == 0 and b.returncode == 0
    fresh = sorted(p.name for p in (pkg / "__pycache__").glob("a.g-9.*"))
    assert fresh == ["a.g-9.py311.1.nbc", "a.g-9.py311.nbi"], "a worker's new kernels deleted"
    assert not any(f.exists() for f in stale)
    assert (int(out_b), int(out_a)) == (2, 0)  # B purged both stale files, A found B's stamp
    assert stamp.read_text() == kernel_cache.sources_stamp(pkg)
    assert sorted(p.name for p in (pkg / "__pycache__").iterdir() if "tmp" in p.name) == []


# A worker of the fresh copy: waits for the start signal, imports the package (which runs the
# check), compiles or loads every kernel, estimates F of a synthetic pair with its kernels and
# prints what it did. A numba warning (a kernel it could not cache or load) is an error.
WORKER = textwrap.dedent(
    """
    import json, sys, time, warnings
    from pathlib import Path

    import numpy as np
    from numba.core.errors import NumbaWarning

    warnings.simplefilter("error", NumbaWarning)
    ready, go = Path(sys.argv[1]), Path(sys.argv[2])
    ready.touch()
    while not go.exists():
        time.sleep(0.005)
    import sepfm_ros
    from sepfm_ros.geometry import estimate_fundamental, symmetric_epipolar_distance
    from sepfm_ros.warm_up import warm_up_report

    report = warm_up_report()
    rng = np.random.default_rng(int(sys.argv[3]))
    K = np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]])
    X = rng.uniform([-2, -2, 4], [2, 2, 8], (150, 3))
    R = np.array([[0.995, 0, 0.0998], [0, 1, 0], [-0.0998, 0, 0.995]])
    t = np.array([0.5, 0.05, 0.0])
    x1 = X @ K.T
    x2 = (X @ R.T + t) @ K.T
    pts1, pts2 = x1[:, :2] / x1[:, 2:], x2[:, :2] / x2[:, 2:]
    est = estimate_fundamental(pts1, pts2, (640, 480), seed=0)
    err = float(np.max(symmetric_epipolar_distance(est.F, pts1, pts2)))
    print(json.dumps({
        "package": sepfm_ros.__file__, "compiled": report.compiled, "loaded": report.loaded,
        "cache_dirs": report.cache_dirs, "ok": bool(est.ok), "max_error_px": err,
    }))
    """
)


@pytest.mark.slow
def test_workers_starting_at_once_on_an_updated_install_share_one_cache(tmp_path):
    # a fresh copy of the sources with a previous version's kernels and stamp in its cache
    src = tmp_path / "site" / "sepfm_ros"
    shutil.copytree(REPO / "sepfm_ros", src, ignore=shutil.ignore_patterns("__pycache__"))
    (src / "__pycache__").mkdir()
    stale = src / "geometry" / "__pycache__" / "estimator.stale-1.py311.nbi"
    stale.parent.mkdir()
    stale.write_bytes(b"previous version")
    (src / "__pycache__" / kernel_cache.STAMP.name).write_text("previous version")
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env["PYTHONPATH"] = str(src.parent)
    go = tmp_path / "go"

    def start(i: int) -> subprocess.Popen:
        ready = tmp_path / f"ready{i}"
        p = subprocess.Popen(
            [sys.executable, "-c", WORKER, str(ready), str(go), str(i)],
            env=env,
            cwd=tmp_path,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        return p

    n_workers = 3
    workers = [start(i) for i in range(n_workers)]
    try:
        _wait_for(lambda: all((tmp_path / f"ready{i}").exists() for i in range(n_workers)), "ready")
        go.touch()  # all import the package at once
        outs = [w.communicate(timeout=1800) for w in workers]
    finally:
        for w in workers:
            w.kill()
    reports = []
    for w, (out, err) in zip(workers, outs, strict=True):
        assert w.returncode == 0, err
        reports.append(json.loads(out.strip().splitlines()[-1]))
    for r in reports:
        assert r["package"] == str(src / "__init__.py")
        assert r["cache_dirs"] and all(d.startswith(str(src)) for d in r["cache_dirs"])
        assert r["ok"] and r["max_error_px"] < 0.5, r
    assert not stale.exists()
    # the cache the workers left is complete: a later process compiles nothing
    later = subprocess.run(
        [sys.executable, "-m", "sepfm_ros", "warm_up"],
        env=env,
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert later.returncode == 0, later.stderr
    assert "nothing to compile" in later.stdout, later.stdout
