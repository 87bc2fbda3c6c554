"""Ray against Dask distributed as the audit's engine, on the same small run.

For each engine (both must be installed: ``pip install 'dask[distributed]' ray``):

- start-up: seconds from nothing to a local cluster of 2 worker processes that has answered
  one task (the audit's start-up cost when it runs locally);
- overhead per task: wall time per task of ``--tasks`` no-op tasks submitted at once and
  gathered as they finish, after the start-up (what the engine adds to each slice of a bag);
- memory per worker: resident set (MiB) of each worker process after the tasks, the engine's
  own share of a worker's memory (the audit's bag reading and pipeline come on top);
- install size: MiB of the installed files of the engine and of the packages it pulls in that
  this project does not need otherwise (from the wheels' RECORD files).

    python benchmarks/bench_engines.py [--tasks 500] [--write-docs]
"""

from __future__ import annotations

import argparse
import importlib.metadata as md
import os
import re
import sys
import time
from collections.abc import Callable
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_docs import captured_stdout, command_line, section, write_section  # noqa: E402

WORKERS = 2
# distributions the project installs anyway (not counted in an engine's install size)
PROJECT_DISTS = {"numpy", "opencv-contrib-python-headless", "rosbags", "matplotlib", "tqdm"}


def noop(x: int) -> int:
    """The task: nothing, so the time measured is the engine's."""
    return x


def worker_pid(_: int) -> int:
    """The process id of the worker that runs this task."""
    return os.getpid()


def _dist_closure(name: str, extras: tuple[str, ...] = ()) -> set[str]:
    """The installed distributions ``name`` (with ``extras``) requires, itself included."""
    seen: set[str] = set()
    todo = [(name, extras)]
    while todo:
        dist, ex = todo.pop()
        key = dist.lower().replace("_", "-")
        if key in seen:
            continue
        try:
            reqs = md.requires(dist) or []
        except md.PackageNotFoundError:
            continue
        seen.add(key)
        for req in reqs:
            m = re.match(r"([A-Za-z0-9_.\-]+)(\[[^\]]*\])?", req)
            if m is None:
                continue
            marker = req.split(";", 1)[1] if ";" in req else ""
            if "extra" in marker and not any(f'"{e}"' in marker for e in ex):
                continue
            sub = tuple(s.strip() for s in (m.group(2) or "[]")[1:-1].split(",") if s.strip())
            todo.append((m.group(1), sub))
    return seen


def _project_closure() -> set[str]:
    out: set[str] = set()
    for d in PROJECT_DISTS:
        out |= _dist_closure(d)
    return out


def install_mib(name: str, extras: tuple[str, ...] = ()) -> float:
    """MiB on disk of the files (compiled ``.pyc`` too) of ``name``'s closure that the
    project's own closure does not have."""
    total = 0
    for dist in _dist_closure(name, extras) - _project_closure():
        for f in md.distribution(dist).files or []:
            path = Path(str(f.locate()))
            if path.is_file():
                total += path.stat().st_size
    return total / 2**20


def _rss_mib(pids: list[int]) -> list[float]:
    import psutil

    return [psutil.Process(p).memory_info().rss / 2**20 for p in pids]


def measure_dask(tasks: int) -> dict[str, float]:
    from dask.distributed import Client, LocalCluster, as_completed

    t0 = time.perf_counter()
    cluster = LocalCluster(
        n_workers=WORKERS, threads_per_worker=1, processes=True, dashboard_address=None
    )
    client = Client(cluster)
    client.submit(noop, 0, pure=False).result()
    startup = time.perf_counter() - t0
    t0 = time.perf_counter()
    futures = [client.submit(noop, i, pure=False) for i in range(tasks)]
    for f in as_completed(futures):
        f.result()
    per_task = (time.perf_counter() - t0) / tasks
    pids = list(client.run(os.getpid).values())
    rss = _rss_mib(pids)
    client.close()
    cluster.close()
    return {"startup_s": startup, "per_task_ms": per_task * 1e3, "rss_mib": max(rss)}


def measure_ray(tasks: int) -> dict[str, float]:
    import ray

    t0 = time.perf_counter()
    ray.init(num_cpus=WORKERS, include_dashboard=False, log_to_driver=False)
    remote = ray.remote(num_cpus=1)(noop)
    ray.get(remote.remote(0))
    startup = time.perf_counter() - t0
    t0 = time.perf_counter()
    pending = [remote.remote(i) for i in range(tasks)]
    while pending:
        done, pending = ray.wait(pending, num_returns=1)
        ray.get(done)
    per_task = (time.perf_counter() - t0) / tasks
    pidf = ray.remote(num_cpus=1)(worker_pid)
    pids = sorted(set(ray.get([pidf.remote(i) for i in range(4 * WORKERS)])))
    rss = _rss_mib(pids)
    # the processes Ray starts besides the workers (raylet, GCS, dashboard agent, ...)
    import psutil

    me = psutil.Process()
    others = [
        p.memory_info().rss / 2**20
        for p in psutil.process_iter()
        if p.pid not in pids and p.pid != me.pid and _is_ray_daemon(p)
    ]
    ray.shutdown()
    return {
        "startup_s": startup,
        "per_task_ms": per_task * 1e3,
        "rss_mib": max(rss),
        "daemons_mib": sum(others),
    }


def _is_ray_daemon(p) -> bool:
    try:
        cmd = " ".join(p.cmdline())
    except Exception:  # noqa: BLE001 - a process that ended or is not ours
        return False
    return "ray" in cmd and ("raylet" in cmd or "gcs_server" in cmd or "ray/" in cmd)


ENGINES: dict[str, tuple[Callable[[int], dict[str, float]], str, tuple[str, ...]]] = {
    "Dask distributed": (measure_dask, "distributed", ()),
    "Ray": (measure_ray, "ray", ()),
}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tasks", type=int, default=500)
    ap.add_argument("--write-docs", action="store_true")
    a = ap.parse_args(argv)
    with captured_stdout() as out:
        print(
            f"Local cluster of {WORKERS} worker processes (one thread each) on this machine, "
            f"{a.tasks} no-op tasks submitted at once and collected as they finish.\n"
        )
        print(
            "| engine | version | start-up (s) | overhead per task (ms) | "
            "worker RSS (MiB) | other daemons RSS (MiB) | install (MiB) |"
        )
        print("|---|---|---:|---:|---:|---:|---:|")
        for name, (measure, dist, extras) in ENGINES.items():
            r = measure(a.tasks)
            size = install_mib(dist, extras)
            if dist == "distributed":
                size += install_mib("dask") if "dask" not in _dist_closure(dist) else 0.0
            print(
                f"| {name} | {md.version(dist)} | {r['startup_s']:.1f} | "
                f"{r['per_task_ms']:.2f} | {r['rss_mib']:.0f} | "
                f"{r.get('daemons_mib', 0.0):.0f} | {size:.0f} |",
                flush=True,
            )
        print(
            "\nDask's scheduler runs in the driver process (its memory is in the driver's, not "
            "listed); Ray's runs in separate daemons (GCS, raylet, agents) whose memory is the "
            "'other daemons' column."
        )
    if a.write_docs:
        body = out.text
        path = write_section(
            "bench_engines",
            section(
                "bench_engines",
                "Audit engine: Ray against Dask distributed",
                command_line("bench_engines.py", argv),
                body,
            ),
        )
        print(f"wrote {path}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
