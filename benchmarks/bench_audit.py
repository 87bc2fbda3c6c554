"""Throughput of ``sepfm_ros audit`` on a test fleet: the engine against a plain loop.

    python benchmarks/bench_audit.py [--rigs 4] [--bags-per-rig 2] [--frames 30] [--write-docs]

The fleet is ``sepfm_ros.ros.bags.synthetic_fleet``'s (KITTI stereo 1241x376 with camera_info at
10 Hz, half the rigs pitching by 0.5 degrees part way). The same bags are audited by:

- ``sequential loop``: this process calls the audit's two tasks (inspect the bag, answer its
  pairs) bag after bag, no engine: the work itself;
- ``local, 1 worker`` and ``local, 2 workers``: the audit's default engine, a Dask cluster
  started in-process with that many single-threaded worker processes;
- ``two-node cluster``: a scheduler and two workers started with the ``dask scheduler`` and
  ``dask worker ADDRESS`` commands, as on two machines, joined by ``--address``.

Every engine run is timed after its workers have loaded the compiled kernels (``warm_up`` on
each) and its start-up is given apart. On this 2-core machine the figures measure the engine's
overhead, not scaling: the per-bag seconds of the sequential loop are what a cluster divides by
its worker count.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_docs import captured_stdout, command_line, section, write_section  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
DATA = REPO.parent / "shared" / "data"


def _warm(client: Any) -> None:
    from sepfm_ros.pipeline.compiled import warm_up

    client.run(warm_up)


def _options(slice_s: float) -> Any:
    from sepfm_ros.fleet.records import InputChoice, Thresholds
    from sepfm_ros.ros.offline.audit import Options
    from sepfm_ros.ros.session.parameters import parse_params

    return Options(parse_params([]), InputChoice(), slice_s, Thresholds(), None, False)


def run_engine(bags: list[Path], out: Path, connect: Callable[[], Any]) -> dict[str, float]:
    """Start the engine (``connect``), warm its workers, then audit ``bags`` into ``out``."""
    from sepfm_ros.fleet.ledger import Ledger
    from sepfm_ros.ros.offline.audit import Driver, bag_keys

    opts = _options(60.0)
    t0 = time.perf_counter()
    with connect() as client:
        startup = time.perf_counter() - t0
        _warm(client)
        keys = bag_keys(bags, opts)
        ledger = Ledger.open(out)
        t1 = time.perf_counter()
        Driver(client, ledger, opts, keys).run(list(keys))
        elapsed = time.perf_counter() - t1
    pairs = sum(int(r["pairs"]) for r in ledger.rows.values())
    return {"startup_s": startup, "elapsed_s": elapsed, "pairs": pairs}


def run_sequential(bags: list[Path]) -> dict[str, float]:
    """The audit's tasks called one after another in this process."""
    from sepfm_ros.fleet.records import SliceTask, TaskFailure
    from sepfm_ros.fleet.slices import overlap_ns, plan_slices
    from sepfm_ros.pipeline.compiled import warm_up
    from sepfm_ros.ros.offline.audit_slices import audit_slice, inspect_bag

    opts = _options(60.0)
    warm_up()
    t0 = time.perf_counter()
    pairs = 0
    for bag in bags:
        info = inspect_bag(str(bag), opts.params, opts.choice)
        if isinstance(info, TaskFailure):
            raise RuntimeError(info.reason)
        slices = plan_slices(info.start_ns, info.end_ns, opts.slice_s)
        overlap = overlap_ns(opts.params, info.period_ns, info.slop_ns)
        for j, (a, b) in enumerate(slices):
            result = audit_slice(SliceTask(info, j, len(slices), a, b, a - overlap, opts.params))
            if isinstance(result, TaskFailure):
                raise RuntimeError(result.reason)
            pairs += len(result.pairs)
    return {"startup_s": 0.0, "elapsed_s": time.perf_counter() - t0, "pairs": pairs}


class TwoNodes:
    """A scheduler and two worker processes started by the ``dask`` command, as on two
    machines; a context manager giving a client joined by address."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.procs: list[subprocess.Popen] = []

    def __enter__(self) -> Any:
        from distributed import Client

        dask = str(Path(sys.executable).parent / "dask")
        sched = self.folder / "scheduler.json"
        log = (self.folder / "cluster.log").open("w")
        self.procs.append(
            subprocess.Popen(
                [
                    dask,
                    "scheduler",
                    "--port",
                    "0",
                    "--no-dashboard",
                    "--scheduler-file",
                    str(sched),
                ],
                stdout=log,
                stderr=log,
            )  # fmt: skip
        )
        deadline = time.monotonic() + 60
        while not sched.is_file() and time.monotonic() < deadline:
            time.sleep(0.1)
        for _ in range(2):
            self.procs.append(
                subprocess.Popen(
                    [
                        dask,
                        "worker",
                        "--scheduler-file",
                        str(sched),
                        "--nthreads",
                        "1",
                        "--no-dashboard",
                    ],
                    stdout=log,
                    stderr=log,
                )  # fmt: skip
            )
        self.client = Client(scheduler_file=str(sched), timeout="60s")
        self.client.wait_for_workers(2, timeout=120)
        return self.client

    def __exit__(self, *exc: object) -> None:
        self.client.close()
        for p in reversed(self.procs):
            p.terminate()
            p.wait(timeout=30)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rigs", type=int, default=4)
    ap.add_argument("--bags-per-rig", type=int, default=2)
    ap.add_argument("--frames", type=int, default=30, help="frames per bag (KITTI has 51)")
    ap.add_argument("--write-docs", action="store_true")
    a = ap.parse_args(argv)
    from sepfm_ros.fleet.engine import engine
    from sepfm_ros.ros.bags.synthetic_fleet import RigPlan, make_fleet

    work = Path(tempfile.mkdtemp(prefix="bench_audit_"))
    try:
        plans = [
            RigPlan(f"robot_{k}", (a.bags_per_rig - 1, a.frames // 2) if k % 2 else None)
            for k in range(a.rigs)
        ]
        fleet = make_fleet(work / "bags", DATA, plans, a.bags_per_rig, a.frames)
        bags = [b.path for b in fleet]
        configs: dict[str, Callable[[Path], dict[str, float]]] = {
            "sequential loop (no engine)": lambda out: run_sequential(bags),
            "local, 1 worker": lambda out: run_engine(bags, out, lambda: engine(None, 1)),
            "local, 2 workers": lambda out: run_engine(bags, out, lambda: engine(None, 2)),
            "two-node cluster (dask scheduler + 2 dask worker)": lambda out: run_engine(
                bags, out, lambda: TwoNodes(out.parent)
            ),
        }
        with captured_stdout() as out:
            print(
                f"{len(bags)} bags ({a.rigs} rigs x {a.bags_per_rig}) of {a.frames} KITTI "
                f"stereo pairs (1241x376, camera_info, calibration check), "
                f"{len(bags) * a.frames} pairs; one slice per bag (each under the 60 s "
                "default). Timed after the workers loaded the kernels.\n"
            )
            print(
                "| run | start-up (s) | audit (s) | bags/min | pairs/s | s per bag | "
                "vs sequential |"
            )
            print("|---|---:|---:|---:|---:|---:|---:|")
            base = None
            for k, (name, run) in enumerate(configs.items()):
                folder = work / f"run{k}"
                folder.mkdir()
                r = run(folder / "out")
                el = r["elapsed_s"]
                base = base or el
                print(
                    f"| {name} | {r['startup_s']:.1f} | {el:.1f} | {60 * len(bags) / el:.1f} | "
                    f"{r['pairs'] / el:.1f} | {el / len(bags):.2f} | {el / base:.2f} |",
                    flush=True,
                )
            print(
                f"\nOn {os.cpu_count()} cores, which the workers share with the driver (and the "
                "cluster's scheduler), these rows measure the engine's overhead against the plain "
                "loop more than its scaling: a cluster of N machines like this one divides the "
                "sequential loop's seconds per bag by about N (each bag, or each 60 s slice of a "
                "long bag, is one task)."
            )
    finally:
        shutil.rmtree(work, ignore_errors=True)
    if a.write_docs:
        body = section(
            "bench_audit",
            "Fleet audit throughput (sepfm_ros audit)",
            command_line("bench_audit.py", argv),
            out.text,
        )
        print(f"wrote {write_section('bench_audit', body)}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
