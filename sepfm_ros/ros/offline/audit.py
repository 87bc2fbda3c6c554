"""The fleet audit's driver: bags to slices on the engine, rows into the ledger, the report
(``sepfm_ros audit``'s library)."""

from __future__ import annotations

import sys
import uuid
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tqdm import tqdm

import sepfm_ros
from sepfm_ros.fleet.discovery import bag_fingerprint, find_bags
from sepfm_ros.fleet.engine import default_workers, engine, outcome, submit
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
    naming_conflicts,
    rig_identity,
    rig_name,
)
from sepfm_ros.fleet.slices import overlap_ns, plan_slices
from sepfm_ros.ros.bags.errors import BagError
from sepfm_ros.ros.offline.audit_slices import audit_slice, inspect_bag

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
