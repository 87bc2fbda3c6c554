"""benchmarks/bench_self_heal.py in its quick mode: the tables it prints parse, the corrections
it reports are near the truth, and the section it writes."""

from __future__ import annotations

import re
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
import bench_self_heal  # noqa: E402

pytestmark = pytest.mark.slow  # half a minute to two minutes on 2 busy cores


def test_quick_run_prints_and_writes_docs(shared_data, tmp_path, capsys):
    doc = tmp_path / "benchmarks.md"
    assert bench_self_heal.main(["--quick", "--write-docs", "--doc", str(doc)]) == 0
    out = capsys.readouterr().out
    rows = re.findall(
        r"^\| (kitti|synthetic \(seed 0\)) \| 0\.5 deg (pitch|roll) \| 10 \| (\d+)/(\d+) \| "
        r"([-+][\d.]+)[^|]* \| ([-+][\d.]+)[^|]* \|",
        out,
        re.M,
    )
    assert len(rows) == 4, out
    for _rig, _axis, issued, trials, err_pitch, err_roll in rows:
        assert int(issued) == int(trials) >= 1
        assert abs(float(err_pitch)) < 0.03 and abs(float(err_roll)) < 0.06
    images = re.findall(
        r"^\| (kitti|synthetic \(seed 0\)) \| 0\.5 deg (pitch|roll) \| ([\d.]+) / ([\d.]+) / "
        r"([\d.]+) \| ([\d.]+) / ([\d.]+) / ([\d.]+) \|",
        out,
        re.M,
    )
    assert len(images) == 4
    for _, _axis, stale, corrected, true, *_ in images:
        assert float(corrected) < 0.5 < float(stale)
        assert float(corrected) <= float(true) + 0.2
    clean = re.findall(
        r"^\| (kitti|synthetic \(seed 0\)) \| [^|]+ \| 0/(\d+) \| 0/(\d+) \|", out, re.M
    )
    assert len(clean) == 2, "a clean rig got a correction"
    # where the roll error comes from: a half-pixel row shift of the right image moves pitch
    # alone, for the exact matches (the fit) and for the tracked points of KITTI's images
    # (ORB's keypoints alone moved roll by 0.014 deg here)
    sources = dict(
        re.findall(
            r"^\| (kitti|synthetic \(seed 0\)) \| [^|]+ \| ([-+][\d.]+ / [-+][\d.]+ / "
            r"[-+][\d.]+) \| [^|]+ \|$",
            out,
            re.M,
        )
    )
    assert set(sources) == {"kitti", "synthetic (seed 0)"}, out
    pitch, yaw, roll = (float(v) for v in sources["kitti"].split(" / "))
    assert -0.045 < pitch < -0.035 and abs(roll) < 0.006 and abs(yaw) < 0.02
    exact = re.search(r"^\| synthetic \(seed 0\) \| .* \| ([-+][\d.]+) / ([-+][\d.]+) / "
                      r"([-+][\d.]+) \|$", out, re.M)  # fmt: skip
    assert exact is not None
    assert float(exact[1]) < -0.07 and abs(float(exact[2])) <= 0.003 >= abs(float(exact[3]))
    text = doc.read_text()
    assert "<!-- bench_self_heal:begin -->" in text
    assert "python benchmarks/bench_self_heal.py --quick" in text
