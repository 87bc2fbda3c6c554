"""Bags written by sepfm_ros 0.1.0 stay readable: the committed fixtures of
``test/ros/data/bags_written_by_0.1.0`` (see its README: a calibrated synthetic stereo input bag
made by ``make_bag`` and the results bag ``process`` wrote for it, whose ``~/calibration_check``
is a bare DiagnosticStatus and whose TwoViewEstimate is 0.1.0's) are read by the readers of
today: ``read_results`` and ``read_calibration_checks`` (``process``'s summary, ``demo``),
``process`` on the input bag, ``eval --bags`` on both, and ``audit`` on the input bag."""

from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("rclpy")

from sepfm_ros.demo import calibration_summary  # noqa: E402
from sepfm_ros.evaluation import cli  # noqa: E402
from sepfm_ros.evaluation.bags import load_bag_pairs  # noqa: E402
from sepfm_ros.ros.bags.reader import BagReader  # noqa: E402
from sepfm_ros.ros.bags.results import read_calibration_checks, read_results  # noqa: E402
from sepfm_ros.ros.commands import process  # noqa: E402

pytestmark = pytest.mark.slow  # process, eval and audit end to end, a few minutes

REPO = Path(__file__).resolve().parents[2]
FIXTURES = REPO / "test" / "ros" / "data" / "bags_written_by_0.1.0"
INPUT, RESULTS = FIXTURES / "input_stereo", FIXTURES / "results_stereo"
STAMPS = [1_700_000_000_000_000_000 + k * 100_000_000 for k in range(3)]  # 10 Hz from 1.7e9 s


def test_the_fixtures_are_what_0_1_0_wrote():
    """Guards the fixtures themselves: the old type is still in them (not regenerated)."""
    with BagReader(RESULTS) as reader:
        assert reader.topics["/sepfm/calibration_check"].msgtype == (
            "diagnostic_msgs/msg/DiagnosticStatus"
        )
        assert reader.topics["/sepfm/estimate"].count == 3
        (estimate,) = [c for c in reader._reader.connections if c.topic == "/sepfm/estimate"]
        assert "line_search_skipped" not in estimate.msgdef.data  # 0.1.0's TwoViewEstimate


def test_results_bag_reads_with_its_answers_and_calibration_checks():
    results = read_results(RESULTS)
    assert [r.stamp_ns for r in results] == STAMPS
    # as process 0.1.0 printed for it: median 0.386 px, max 0.392 px against ground truth
    assert all(r.F is not None and r.status == "ok" and r.inliers > 100 for r in results)
    assert [round(r.error_px, 3) for r in results] == [0.392, 0.377, 0.386]
    # 0.1.0's TwoViewEstimate, read as today's: the fields after the one added since keep
    # their values, and the new line_search_skipped reads False (no escape in 0.1.0)
    assert all(r.estimate.line_search_skipped is False for r in results)
    assert all(r.estimate.line_inliers > 0 and r.estimate.has_line_pair for r in results)
    assert [r.estimate.method for r in results] == ["sep4"] * 3
    with BagReader(RESULTS) as reader:
        assert "sepfm_msgs/msg/TwoViewEstimate" in reader.migrated
    checks = read_calibration_checks(RESULTS)
    assert [c.log_time_ns for c in checks] == STAMPS  # one per pair, logged with it
    assert all(c.stamp_ns is None for c in checks)  # the bare status had no header
    assert {c.status.name for c in checks} == {"sepfm: calibration"}  # 0.1.0's name
    assert [c.status.level for c in checks] == [b"\x03"] * 3  # STALE: 3 of 5 pairs needed
    assert checks[-1].status.message.startswith("calibration not checked: 3 of 5 pairs")
    line = calibration_summary(RESULTS, results)
    assert line is not None and "3 pairs" in line and "calibration check STALE" in line


def test_process_reads_the_input_bag_and_writes_stamped_checks(tmp_path):
    out = tmp_path / "out"
    assert process.main([str(INPUT), "-o", str(out), "-p", "seed:=0", "--quiet"]) == 0
    results = read_results(out)
    assert [r.stamp_ns for r in results] == STAMPS
    assert all(r.F is not None and r.error_px < 1.0 for r in results)
    checks = read_calibration_checks(out)
    assert [c.stamp_ns for c in checks] == STAMPS  # now stamped with the pair's header
    assert {c.status.name for c in checks} == {"/sepfm: calibration"}
    assert [c.status.level for c in checks] == [b"\x03"] * 3


@pytest.mark.parametrize("bag", [INPUT, RESULTS], ids=["input", "results"])
def test_eval_bags_reads_both(bag, tmp_path):
    pairs, errors = load_bag_pairs(bag, tmp_path / "frames")
    assert errors == [] and len(pairs) == 3
    out = tmp_path / "out"
    argv = ["--bags", str(bag), "--out", str(out), "--cache", "none",
            "--methods", "ransac8", "--seeds", "0", "--no-progress"]  # fmt: skip
    assert cli.main(argv) == 0
    with open(out / "runs.csv", newline="") as f:
        runs = list(csv.DictReader(f))
    assert len(runs) == 3 and all(float(r["f_score"]) > 0.9 for r in runs)


def test_audit_reads_the_input_bag(tmp_path):
    """audit answers input bags (a results bag has no images: it gets a row saying so)."""
    out = tmp_path / "audit"
    run = subprocess.run(
        [sys.executable, "-m", "sepfm_ros", "audit", "--quiet", str(INPUT),
         "-o", str(out), "--workers", "1"],
        cwd=tmp_path, capture_output=True, text=True, timeout=900,
    )  # fmt: skip
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-2000:]
    with open(out / "bags.csv", newline="") as f:
        (row,) = list(csv.DictReader(f))
    assert Path(row["bag"]).name == "input_stereo" and row["state"] == "done"
    assert row["calibrated"] == "True" and row["mode"] == "stereo"
    assert row["pairs"] == "3" and row["pairs_with_f"] == "3"
    assert row["worst_level"] == "STALE"  # 3 pairs: fewer than the check's 5
