"""benchmarks/bench_ablation.py on two shared pairs: one row per configuration and anchor, with
figures in range, and the docs it writes (its section of docs/benchmarks.md)."""

from __future__ import annotations

import re
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
import bench_ablation  # noqa: E402
import bench_docs  # noqa: E402
import compiled_work  # noqa: E402

from sepfm_ros.evaluation.methods import superansac_methods  # noqa: E402
from sepfm_ros.geometry import DEFAULT_METHOD  # noqa: E402


def test_two_pairs_every_configuration_printed_and_written(shared_data, tmp_path, capsys):
    doc = tmp_path / "benchmarks.md"
    doc.write_text(bench_docs.empty_document())
    argv = ["--sets", "shared", "--step", "100", "--write-docs", "--doc", str(doc)]
    assert bench_ablation.main(argv) == 0
    out = capsys.readouterr().out
    assert "(2 pairs: every 100th of pairs.json; seed 0)" in out
    labels = [f"{DEFAULT_METHOD} (default)"] + [k for k in bench_ablation.CONFIGS if k != "default"]
    labels += bench_ablation.ANCHORS
    assert set(superansac_methods()) <= set(bench_ablation.ANCHORS)  # where installed
    for label in labels:
        row = re.search(rf"^\| {re.escape(label)} \| (\S+) \| (\S+) \| (\S+) \| (\S+) \| (\S+) "
                        r"\| ([^|]+) \| ([^|]+) \|$", out, re.M)  # fmt: skip
        assert row, label
        f, success = float(row.group(1)), float(row.group(2))
        assert 0.0 <= f <= 1.0 and 0.0 <= success <= 100.0
        assert float(row.group(4)) > 0
        if label.startswith("superansac"):  # its returned iterations
            assert int(row.group(3)) > 0
        lines = re.fullmatch(r"(\d+\.\d\d) \((\d+)%\)", row.group(6))
        share = re.fullmatch(r"(\d+) \((\d+)\)", row.group(7))
        if label == "escape off (line search on every pair)":
            assert lines and float(lines.group(1)) > 0 and 0 < int(lines.group(2)) <= 100, row[0]
            assert share and int(share.group(1)) == 100, row[0]  # every pair ran it
        if label.startswith(DEFAULT_METHOD):  # pairs that ran the line search, and used a pair
            assert share and 0 <= int(share.group(2)) <= int(share.group(1)) <= 100, row[0]
        if label in bench_ablation.ANCHORS:
            assert row.group(6) == row.group(7) == "n/a"
    assert re.search(r"^\| cv-magsac \| .* \| 1\.00 \| n/a \| n/a \|$", out, re.M)
    # where the default method's time goes: stage means that add up to the total
    stages = re.search(r"^\| ((?:\d+\.\d\d \| ){6})(\d+\.\d\d) \| (\d+\.\d\d); (\d+\.\d\d) \|$",
                       out, re.M)  # fmt: skip
    assert stages, out
    parts = [float(v) for v in stages.group(1).split(" | ") if v]
    assert all(v >= 0 for v in parts[:5]) and float(stages.group(2)) > 0
    assert abs(sum(parts) - float(stages.group(2))) <= 0.035  # 7 figures rounded to 0.005
    body = bench_docs.read_block(doc.read_text(), "bench_ablation")
    assert body.startswith(f"## Ablation of the default method ({DEFAULT_METHOD})")
    assert "Not generated yet" in bench_docs.read_block(doc.read_text(), "bench_estimators")
    assert f"| {DEFAULT_METHOD} (default) |" in body
    # the compiled work against the required ratio, consistent with its own figures
    note = re.search(
        r"^Compiled work .*: median (\d+\.\d\d) ms per pair, (\d+\.\d\d)x USAC_MAGSAC's median; "
        r"the method's median (\d+\.\d\d) ms is (\d+\.\d\d)x\. Required: at most 1\.25x "
        r"\((\d+\.\d\d) ms\); the compiled work alone is (above|within) it\.$",
        out,
        re.M,
    )
    assert note, out
    compiled, measured, allowed = float(note[1]), float(note[3]), float(note[5])
    assert 0 < compiled <= measured
    assert note[6] == ("above" if compiled > allowed else "within")


def test_compiled_share_tells_kernels_from_python():
    """A call that spends its time in a numba kernel is mostly compiled; a Python loop is not."""
    import numpy as np

    from sepfm_ros.geometry.epipolar import msac_kernel

    rng = np.random.default_rng(0)
    X = np.ascontiguousarray(np.vstack([rng.random((2, 200_000)), np.ones((1, 200_000))]))
    F = np.ascontiguousarray(rng.normal(size=(8, 3, 3)))
    msac_kernel(F, X, X, 1.0)  # compiled before it is measured
    assert compiled_work.compiled_share(lambda: msac_kernel(F, X, X, 1.0)) > 0.9

    def python_loop() -> float:
        return sum(float(i) ** 0.5 for i in range(100_000))

    assert compiled_work.compiled_share(python_loop) < 0.05
