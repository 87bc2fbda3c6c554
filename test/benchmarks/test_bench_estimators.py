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


def test_each_method_is_timed_after_an_untimed_run_of_itself(shared_data, monkeypatch):
    """On each pair, every method runs once untimed before its seeds (compiled_work.warm_up), so
    the method timed first on a pair does not follow another library's runs."""
    from dataclasses import replace

    from sepfm_ros.evaluation import methods

    calls: list[tuple[str, int]] = []
    for name in ("sep4", "cv-magsac"):
        original = methods.REGISTRY[name]

        def counted(*args, _name=name, _run=original.run):
            calls.append((_name, args[-1]))
            return _run(*args)

        monkeypatch.setitem(methods.REGISTRY, name, replace(original, run=counted))
    pairs, _ = load_manifest(shared_data / "pairs.json")
    bench_estimators.run_setting(pairs[100:102], 0.75, [3, 4], methods=["sep4", "cv-magsac"])
    # per pair and method: the warm-up (seed 0), then the timed seeds
    one_pair = [("sep4", 0), ("sep4", 3), ("sep4", 4), ("cv-magsac", 0), ("cv-magsac", 3),
                ("cv-magsac", 4)]  # fmt: skip
    assert calls == one_pair * 2
