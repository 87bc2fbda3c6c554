"""``sepfm_ros audit BAGS... -o OUT``: every rig's calibration across many bags, on Dask.

BAGS are bags (rosbag2 folders, ``.mcap``, ``.db3``, ROS 1 ``.bag``), folders searched for bags,
glob patterns or text files listing them. Each bag is read on a worker of the engine (Dask
distributed: a local cluster of one single-threaded worker process per core, or the cluster at
``--address``): its inputs are picked as ``process`` picks them, its rig named by what it says
(camera_info frame ids, K, D, P and topics; ``--rig-from`` names rigs by a path pattern), and
every pair answered by the node's answer path: the calibration check where the bag has
calibrated stereo, otherwise the answer statistics. A bag longer than ``--slice-s`` is split
into time slices that run in parallel and give the same answers as one pass.

OUT gets ``bags.csv`` (a row per bag: rig, time span, topics, pairs, pairs with F, inlier error,
rotation drift against the calibration, worst decision, when the drift starts and when it was
flagged; a bag that cannot be read gets a row with the reason), ``pairs.csv`` (every pair) and
``report.md`` with a drift plot per rig, flagged rigs first. Rows are written by this process as
bags finish; running the same command again skips the bags done (same bag files, parameters
and version) unless ``--force``.

Exit codes: 0 every bag answered and no rig flagged; 1 a rig flagged (WARN or ERROR) or a bag
without an answer; 2 bad arguments or no engine; 130 interrupted (rows written so far stay).
"""

from __future__ import annotations

import argparse
import sys
import uuid
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tqdm import tqdm

import sepfm_ros
from sepfm_ros.fleet.discovery import bag_fingerprint, find_bags
from sepfm_ros.fleet.engine import EngineError, default_workers, engine, outcome, submit
from sepfm_ros.fleet.ledger import Ledger, task_key
from sepfm_ros.fleet.records import (
    BagInfo,
    InputChoice,
    SliceResult,
    SliceTask,
    TaskFailure,
    Thresholds,
    bag_row,
    failed_row,
)
from sepfm_ros.fleet.report import write_report
from sepfm_ros.fleet.rigs import (
    RigPatternError,
    compile_pattern,
    naming_conflicts,
    rig_identity,
    rig_name,
)
from sepfm_ros.fleet.slices import overlap_ns, plan_slices
from sepfm_ros.ros.audit_adapter import audit_slice, inspect_bag
from sepfm_ros.ros.bags.errors import BagError
from sepfm_ros.ros.parameters import monitor_config
from sepfm_ros.ros.process import parse_params

DEFAULT_SLICE_S = 60.0


@dataclass
class Options:
    """One audit run's settings (see :func:`_parse`)."""

    params: dict[str, Any]
    choice: InputChoice
    slice_s: float
    thresholds: Thresholds
    pattern: Any = None
    progress: bool = True


@dataclass
class _BagState:
    """A bag in flight: its description, rig and the slices returned so far."""

    key: str
    info: BagInfo | None = None
    rig: tuple[str, str, str] = ("", "", "")
    slices: int = 0
    results: dict[int, SliceResult] = field(default_factory=dict)
    futures: list[Any] = field(default_factory=list)


def _parse(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        prog="sepfm_ros audit",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("bags", nargs="+", help="bags, folders, glob patterns or .txt lists of bags")
    p.add_argument("-o", "--output", type=Path, required=True, help="output folder")
    p.add_argument(
        "--address",
        help="Dask scheduler of a running cluster (tcp://HOST:8786); default: a local cluster",
    )
    p.add_argument(
        "--workers",
        type=int,
        default=None,
        help=f"worker processes of the local cluster (default: one per core, {default_workers()})",
    )
    p.add_argument(
        "--slice-s",
        type=float,
        default=DEFAULT_SLICE_S,
        help="split bags longer than this into time slices of at most this many seconds (0: never)",
    )
    p.add_argument(
        "--rig-from",
        metavar="REGEX",
        help="name rigs by this regular expression on the bag path (its 'rig' group, else its "
        "first group), e.g. 'robots/(?P<rig>[^/]+)/'; default: by the cameras' camera_info",
    )
    p.add_argument("--force", action="store_true", help="audit bags done in an earlier run again")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.add_argument("--mode", choices=("stereo", "motion"), help="default: from each bag")
    p.add_argument("--left", metavar="TOPIC", help="stereo: left image topic (with --right)")
    p.add_argument("--right", metavar="TOPIC", help="stereo: right image topic (with --left)")
    p.add_argument("--image", metavar="TOPIC", help="motion: the image topic")
    p.add_argument(
        "-p",
        "--param",
        action="append",
        default=[],
        metavar="NAME:=VALUE",
        help="a node parameter (e.g. seed:=0, calibration_window:=10); repeatable",
    )
    return p.parse_args(argv)


def _options(args: argparse.Namespace) -> Options:
    """The run's options; BagError / ValueError / RigPatternError on bad arguments."""
    params = parse_params(args.param)
    monitor = monitor_config(params)
    if args.slice_s < 0:
        raise ValueError(f"--slice-s must be >= 0, got {args.slice_s}")
    if args.workers is not None and args.workers < 1:
        raise ValueError(f"--workers must be >= 1, got {args.workers}")
    choice = InputChoice(
        args.mode,
        args.left,
        args.right,
        args.image,
        any(p.startswith("sync_slop_s:=") for p in args.param),
    )
    return Options(
        params,
        choice,
        args.slice_s,
        Thresholds(monitor.warn_rotation_deg, monitor.error_rotation_deg),
        compile_pattern(args.rig_from),
        not args.quiet,
    )


def bag_keys(bags: Iterable[Path], opts: Options) -> dict[str, str]:
    """bag -> resume key (bag files, parameters and input choice, package version)."""
    settings = {**opts.params, "inputs": vars(opts.choice)}
    return {str(b): task_key(b, bag_fingerprint(b), settings, sepfm_ros.__version__) for b in bags}


def _token() -> str:
    return uuid.uuid4().hex[:8]


class Driver:
    """Submits each bag's inspection, then its slices, and writes each bag's row once all its
    slices are in (or once any task of it failed), as the results arrive."""

    def __init__(self, client: Any, ledger: Ledger, opts: Options, keys: dict[str, str]) -> None:
        from distributed import as_completed

        self.client, self.ledger, self.opts, self.keys = client, ledger, opts, keys
        self.queue = as_completed()
        self.meta: dict[str, tuple[str, str]] = {}  # future key -> (kind, bag)
        self.bags: dict[str, _BagState] = {}
        self.run_id = _token()
        off = not opts.progress
        self.bag_bar = tqdm(total=0, unit="bag", desc="bags", disable=off, file=sys.stderr)
        self.pair_bar = tqdm(total=0, unit="pair", desc="pairs", disable=off, file=sys.stderr)

    def _submit(self, kind: str, bag: str, fn: Any, *args: Any) -> Any:
        key = f"audit-{kind}-{self.run_id}-{_token()}"
        future = submit(self.client, fn, *args, key=key)
        self.meta[future.key] = (kind, bag)
        self.queue.add(future)
        return future

    def run(self, bags: list[str]) -> None:
        self.bag_bar.total = len(bags)
        self.bag_bar.refresh()
        for bag in bags:
            self.bags[bag] = _BagState(self.keys[bag])
            self._submit("inspect", bag, inspect_bag, bag, self.opts.params, self.opts.choice)
        try:
            for future in self.queue:
                kind, bag = self.meta.pop(future.key)
                result, reason = outcome(future)
                if reason is not None:
                    result = TaskFailure(reason)
                if bag not in self.bags:  # finished already (an earlier task of it failed)
                    continue
                if isinstance(result, TaskFailure):
                    self._finish_failed(bag, result.reason)
                elif kind == "inspect":
                    self._plan(bag, result)
                else:
                    self._collect(bag, result)
        finally:
            self.bag_bar.close()
            self.pair_bar.close()

    def _plan(self, bag: str, info: BagInfo) -> None:
        state = self.bags[bag]
        state.info = info
        rig_id, label = rig_identity(info)
        state.rig = (rig_id, rig_name(self.opts.pattern, bag, rig_id), label)
        slices = plan_slices(info.start_ns, info.end_ns, self.opts.slice_s)
        overlap = overlap_ns(self.opts.params, info.period_ns, info.slop_ns)
        state.slices = len(slices)
        self.pair_bar.total += info.expected_pairs
        self.pair_bar.refresh()
        for j, (t0, t1) in enumerate(slices):
            task = SliceTask(info, j, len(slices), t0, t1, t0 - overlap, self.opts.params)
            state.futures.append(self._submit("slice", bag, audit_slice, task))

    def _collect(self, bag: str, result: SliceResult) -> None:
        state = self.bags[bag]
        if result.index in state.results:  # the same slice delivered twice: keep one
            return
        state.results[result.index] = result
        self.pair_bar.update(len(result.pairs))
        if len(state.results) < state.slices:
            return
        assert state.info is not None
        pairs = [p for j in range(state.slices) for p in state.results[j].pairs]
        rig_id, rig, label = state.rig
        row = bag_row(
            state.info, pairs, rig_id, rig, label, state.key, state.slices, self.opts.thresholds
        )
        self._write(bag, row, pairs)

    def _finish_failed(self, bag: str, reason: str) -> None:
        state = self.bags[bag]
        for f in state.futures:
            f.cancel()
        rig_id, rig, label = state.rig
        self._write(bag, failed_row(bag, reason, state.key, rig_id, rig, label), [])

    def _write(self, bag: str, row: Any, pairs: list[Any]) -> None:
        del self.bags[bag]
        self.ledger.write(row, pairs)
        self.bag_bar.update(1)
        what = row.worst_level or ("failed: " + row.reason if row.state == "failed" else "done")
        self.bag_bar.write(
            f"{row.rig}: {Path(bag).name}: {row.pairs} pairs, {what}", file=sys.stderr
        )


def _rename_rigs(ledger: Ledger, pattern: Any) -> list[str]:
    """Every row's rig named with this run's ``--rig-from``; warnings about the naming."""
    rows = list(ledger.rows.values())
    for r in rows:  # a bag that could not be read is named by its path too, when it matches
        r["rig"] = rig_name(pattern, r["bag"], r["rig_id"] or "unknown")
    ledger.rewrite_rows(rows)
    return naming_conflicts((r["rig"], r["rig_id"], r["bag"]) for r in rows)


def run_audit(
    items: list[str], out: Path, opts: Options, address: str | None, workers: int | None,
    force: bool,
) -> tuple[list[dict[str, str]], Path]:  # fmt: skip
    """Audit the bags ``items`` name into ``out``; returns (every row of ``out``, report path).

    Raises BagError when no bag is found, EngineError when the engine cannot start.
    """
    found = find_bags(items)
    for note in found.notes:
        print(f"sepfm_ros audit: {note}", file=sys.stderr)
    if not found.bags:
        raise BagError("no bags found in " + " ".join(items))
    keys = bag_keys(found.bags, opts)
    ledger = Ledger.open(out, keys if force else ())
    todo = []
    for bag in keys:
        if not ledger.done(bag, keys[bag]):
            ledger.forget(bag)
            todo.append(bag)
    skipped = len(keys) - len(todo)
    where = f"the cluster at {address}" if address else f"{workers or default_workers()} workers"
    print(
        f"sepfm_ros audit: {len(keys)} bag(s); {skipped} done in an earlier run into {out} "
        f"(--force audits them again); auditing {len(todo)} on {where}",
        file=sys.stderr,
        flush=True,
    )
    if todo:
        with engine(address, workers) as client:
            Driver(client, ledger, opts, keys).run(todo)
    warnings = _rename_rigs(ledger, opts.pattern)
    for w in warnings:
        print(f"sepfm_ros audit: warning: {w}", file=sys.stderr)
    rows = list(ledger.rows.values())
    report = write_report(out, rows, ledger.pairs(), opts.thresholds, warnings)
    return rows, report


def main(argv: list[str]) -> int:
    args = _parse(argv)
    try:
        opts = _options(args)
        rows, report = run_audit(
            args.bags, args.output, opts, args.address, args.workers, args.force
        )
    except (BagError, ValueError, RigPatternError, EngineError) as err:
        print(f"sepfm_ros audit: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(
            f"sepfm_ros audit: interrupted; {args.output / 'bags.csv'} holds the bags finished "
            "so far (rerun the command to continue)",
            file=sys.stderr,
        )
        return 130
    failed = [r for r in rows if r["state"] != "done"]
    flagged = sorted({r["rig"] for r in rows if r.get("worst_level") in ("WARN", "ERROR")})
    print(
        f"{len(rows)} bag(s): {len(rows) - len(failed)} answered, {len(failed)} without an "
        f"answer; {len(flagged)} rig(s) flagged" + (f": {', '.join(flagged)}" if flagged else "")
    )
    print(f"wrote {args.output / 'bags.csv'}, {args.output / 'pairs.csv'} and {report}")
    return 1 if failed or flagged else 0
