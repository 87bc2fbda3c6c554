"""benchmarks/bench_outliers.py on two shared pairs at one outlier rate: a row per method and
anchor with figures in range, USAC_MAGSAC's time ratio 1.00, the default's F-score against each
anchor, and the section it writes into docs/benchmarks.md."""

from __future__ import annotations

import re
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
import bench_docs  # noqa: E402
import bench_outliers  # noqa: E402

from sepfm_ros.evaluation.methods import superansac_methods  # noqa: E402
from sepfm_ros.geometry import DEFAULT_METHOD  # noqa: E402


def test_two_pairs_every_method_and_anchor_printed_and_written(shared_data, tmp_path, capsys):
    doc = tmp_path / "benchmarks.md"
    doc.write_text(bench_docs.empty_document())
    argv = ["--step", "100", "--rates", "0.6", "--write-docs", "--doc", str(doc)]
    assert bench_outliers.main(argv) == 0
    out = capsys.readouterr().out
    assert "(2 pairs, SIFT 0.8 + random wrong matches)" in out
    assert {"cv-ransac", "cv-magsac", "cv-accurate"} <= set(bench_outliers.ANCHORS)
    assert set(superansac_methods()) <= set(bench_outliers.ANCHORS)  # where installed
    for name in (*bench_outliers.METHODS, *bench_outliers.ANCHORS):
        label = f"{name} (default)" if name == DEFAULT_METHOD else name
        row = re.search(
            rf"^\| 0\.60 \| {re.escape(label)} \| (\S+) \| (\S+) \| (\S+) \| (\S+) \| (\S+) \|$",
            out, re.M,
        )  # fmt: skip
        assert row, label
        success, f, hyp = float(row.group(1)), float(row.group(2)), row.group(3)
        assert 0.0 <= success <= 100.0 and 0.0 <= f <= 1.0
        assert (hyp == "n/a") == name.startswith("cv-")
        assert float(row.group(4)) > 0 and float(row.group(5)) > 0
    assert re.search(r"^\| 0\.60 \| cv-magsac \| .* \| 1\.00 \|$", out, re.M)
    diffs = re.search(rf"{DEFAULT_METHOD} \(default\) F-score minus (.*)$", out, re.M)
    assert diffs and all(f"{n}'s: " in diffs.group(1) for n in bench_outliers.ANCHORS)
    body = bench_docs.read_block(doc.read_text(), "bench_outliers")
    assert body.startswith("## Outlier-rate benchmark (2 pairs")
    assert "`python benchmarks/bench_outliers.py --step 100 --rates 0.6" in body
