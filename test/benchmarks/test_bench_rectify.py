"""benchmarks/bench_rectify.py on a few pairs of each set: the printed table (figures in range,
rectified under the target where the pairs allow) and the section it writes."""

from __future__ import annotations

import re
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
import bench_rectify  # noqa: E402


def test_few_pairs_print_and_write_docs(shared_data, shared_data_lines, tmp_path, capsys):
    doc = tmp_path / "benchmarks.md"
    argv = ["--angles", "2", "--stereo-step", "5", "--temple-step", "51", "--lines-step", "200",
            "--write-docs", "--doc", str(doc)]  # fmt: skip
    assert bench_rectify.main(argv) == 0
    out = capsys.readouterr().out
    rows = re.findall(r"^\| (stereo, right rotated 2 deg|templeRing[^|]*|data_lines[^|]*) \| (\d+) "
                      r"\| ([\d.]+) \| ([\d.]+|n/a) \| (\d+)/(\d+) \|", out, re.M)  # fmt: skip
    assert [r[0].split(",")[0].split(" ")[0] for r in rows] == [
        "stereo",
        "templeRing",
        "data_lines",
    ]
    for name, n, before, after, under, rectified in rows:
        assert int(n) == 2 and float(before) > 1.0
        if name.startswith(("stereo", "templeRing")):
            assert float(after) < bench_rectify.TARGET_PX and under == rectified == "2"
    text = doc.read_text()
    assert "<!-- bench_rectify:begin -->" in text and "stereo, right rotated 2 deg" in text
    assert "python benchmarks/bench_rectify.py --angles 2" in text
