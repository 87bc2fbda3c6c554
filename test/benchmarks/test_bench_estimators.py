"""benchmarks/bench_estimators.py on one shared pair: a row per method in its table and README's
headline, SupeRANSAC's two entries among them where it is installed."""

from __future__ import annotations

import re
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
import bench_estimators  # noqa: E402

from sepfm_ros.evaluation.manifest import load_manifest  # noqa: E402
from sepfm_ros.evaluation.methods import superansac_methods  # noqa: E402


def test_one_pair_a_row_per_method_and_in_the_headline(shared_data):
    pairs, _ = load_manifest(shared_data / "pairs.json")
    rows = bench_estimators.run_setting(pairs[100:101], 0.75, [0])
    assert set(superansac_methods()) <= set(bench_estimators.METHODS)  # where installed
    text = bench_estimators.report(0.75, rows)
    for name in bench_estimators.METHODS:
        row = re.search(rf"^\| {re.escape(name)} \| (\d\.\d{{3}}) ± \S+ \| \S+ \| (\S+) \| "
                        r"(\S+)(?: / \S+)? \| (\S+) \|$", text, re.M)  # fmt: skip
        assert row, name
        assert 0.0 <= float(row.group(1)) <= 1.0 and float(row.group(4)) > 0
        assert (row.group(3) == "n/a") == name.startswith("cv-"), name
    head = bench_estimators.headline({0.75: rows})
    names = re.findall(r"^\| (\S+) \| \d\.\d{3} \| \d+\.\d \|$", head, re.M)
    assert {"sep4", "cv-magsac", *superansac_methods()} <= set(names)
