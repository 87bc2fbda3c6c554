"""The audit's output folder as its ledger: ``bags.csv`` (one row per bag, the fleet table) and
``pairs.csv`` (every answered pair of those bags), written by the driver only, a bag at a time.

A bag's pairs are appended first, then its row, each flushed to disk, so a row exists only for
a bag whose pairs are all written; an interrupted run leaves at most pairs without a row, which
the next run drops. Resuming skips a bag whose row has the same key (bag, parameters, version:
:func:`task_key`); ``force`` drops the rows of the bags about to be audited instead. The engine
delivers a task's result at least once; the ledger writes a bag once (a second row for a bag is
refused), so retries never give two rows.
"""

from __future__ import annotations

import csv
import hashlib
import json
import math
import os
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from sepfm_ros.fleet.records import PAIR_FIELDS, ROW_FIELDS, BagRow, PairRecord

BAGS_CSV = "bags.csv"
PAIRS_CSV = "pairs.csv"
PAIR_COLUMNS = ["rig_id", "bag", *PAIR_FIELDS]


def task_key(bag: Path, fingerprint: tuple[int, int], params: dict[str, Any], version: str) -> str:
    """The resume key of a bag's audit: its path and files (size, mtime), the parameters and
    the package version, hashed."""
    text = json.dumps(
        {"bag": str(bag), "files": list(fingerprint), "params": params, "version": version},
        sort_keys=True,
        default=str,
    )
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _read(path: Path) -> list[dict[str, str]]:
    if not path.is_file():
        return []
    with path.open(newline="") as f:
        return list(csv.DictReader(f))


def _rewrite(path: Path, columns: list[str], rows: Iterable[dict[str, Any]]) -> None:
    tmp = path.with_suffix(".tmp")
    with tmp.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=columns)
        w.writeheader()
        for r in rows:
            w.writerow({c: r.get(c, "") for c in columns})
    os.replace(tmp, path)


def _cell(value: Any) -> Any:
    """A CSV cell: NaN and None (no value) are empty."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return ""
    return value


class DuplicateRowError(RuntimeError):
    """A second row for a bag that has one (a bug in the driver: a result taken twice)."""


class Ledger:
    """The output folder's ``bags.csv`` and ``pairs.csv``; open with :meth:`open`."""

    def __init__(self, out: Path) -> None:
        self.out = out
        self.rows: dict[str, dict[str, str]] = {}  # bag -> its row (this run's and earlier)

    @classmethod
    def open(cls, out: Path, force_bags: Iterable[str] = ()) -> Ledger:
        """The ledger of ``out`` (created when missing): earlier rows kept, except those of
        ``force_bags``; pairs without a row (an interrupted run) dropped."""
        ledger = cls(out)
        out.mkdir(parents=True, exist_ok=True)
        drop = set(force_bags)
        rows = [r for r in _read(out / BAGS_CSV) if r.get("bag") not in drop]
        ledger.rows = {r["bag"]: r for r in rows}
        pairs = [r for r in _read(out / PAIRS_CSV) if r.get("bag") in ledger.rows]
        _rewrite(out / BAGS_CSV, ROW_FIELDS, rows)
        _rewrite(out / PAIRS_CSV, PAIR_COLUMNS, pairs)
        return ledger

    def done(self, bag: str, key: str) -> bool:
        """The bag has a row from a run with the same key."""
        row = self.rows.get(bag)
        return row is not None and row.get("key") == key

    def forget(self, bag: str) -> None:
        """Drop a bag's earlier row and pairs (its key changed: it is audited again)."""
        if bag not in self.rows:
            return
        del self.rows[bag]
        _rewrite(self.out / BAGS_CSV, ROW_FIELDS, self.rows.values())
        pairs = [r for r in _read(self.out / PAIRS_CSV) if r.get("bag") != bag]
        _rewrite(self.out / PAIRS_CSV, PAIR_COLUMNS, pairs)

    def write(self, row: BagRow, pairs: list[PairRecord]) -> None:
        """Append a bag's pairs, then its row, each flushed to disk."""
        if row.bag in self.rows:
            raise DuplicateRowError(f"{row.bag} has a row already")
        with (self.out / PAIRS_CSV).open("a", newline="") as f:
            w = csv.DictWriter(f, fieldnames=PAIR_COLUMNS)
            for p in pairs:
                values = {k: _cell(getattr(p, k)) for k in PAIR_FIELDS}
                w.writerow({"rig_id": row.rig_id, "bag": row.bag, **values})
            f.flush()
            os.fsync(f.fileno())
        cells = {k: _cell(v) for k, v in row.as_csv().items()}
        with (self.out / BAGS_CSV).open("a", newline="") as f:
            csv.DictWriter(f, fieldnames=ROW_FIELDS).writerow(cells)
            f.flush()
            os.fsync(f.fileno())
        self.rows[row.bag] = {k: str(v) for k, v in cells.items()}

    def rewrite_rows(self, rows: list[dict[str, str]]) -> None:
        """Replace the rows (same bags, e.g. renamed rigs)."""
        self.rows = {r["bag"]: r for r in rows}
        _rewrite(self.out / BAGS_CSV, ROW_FIELDS, rows)

    def pairs(self) -> list[dict[str, str]]:
        """Every pair written (this run's and earlier), as CSV rows."""
        return _read(self.out / PAIRS_CSV)
