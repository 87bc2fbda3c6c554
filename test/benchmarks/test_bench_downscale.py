"""benchmarks/bench_downscale.py on two Strecha pairs: both settings run, the table's figures in
range, and the docs section it writes."""

from __future__ import annotations

import re
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
import bench_docs  # noqa: E402
import bench_downscale  # noqa: E402


def test_two_pairs_print_both_settings_and_write_docs(shared_data_lines, tmp_path, capsys):
    doc = tmp_path / "benchmarks.md"
    doc.write_text(bench_docs.empty_document())
    argv = ["--data", str(shared_data_lines), "--max-pairs", "2", "--seeds", "0",
            "--write-docs", "--doc", str(doc)]  # fmt: skip
    assert bench_downscale.main(argv) == 0
    out = capsys.readouterr().out
    rows = re.findall(
        r"^\| (feature_max_width \d+[^|]*) \| (\d+) \| (\d+) \| (\d\.\d{3}) ± \S+ \| (\S+) \|",
        out,
        re.M,
    )
    assert [r[0] for r in rows] == [
        "feature_max_width 0: full size",
        "feature_max_width 1280: downscaled by 2",
    ]
    for _, matches, positives, f, success in rows:
        assert int(matches) >= int(positives) > 0
        assert 0.0 <= float(f) <= 1.0 and 0.0 <= float(success) <= 100.0
    text = doc.read_text()
    section = bench_docs.read_block(text, "bench_downscale")
    assert "python benchmarks/bench_downscale.py --data" in section
    assert "feature_max_width 1280: downscaled by 2" in section
    assert "load average" in section
