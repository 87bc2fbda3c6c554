"""The audit's ROS-free parts: bag discovery, slices, rig naming, the ledger's one row per bag."""

from __future__ import annotations

import csv
import importlib.util
import math

import pytest
from ground_truth import REPO_ROOT

from sepfm_ros.fleet.discovery import find_bags
from sepfm_ros.fleet.ledger import BAGS_CSV, PAIRS_CSV, DuplicateRowError, Ledger
from sepfm_ros.fleet.records import (
    ROW_FIELDS,
    BagInfo,
    BagRow,
    PairRecord,
    Thresholds,
    bag_row,
    drift_start,
)
from sepfm_ros.fleet.rigs import RigPatternError, compile_pattern, naming_conflicts, rig_name
from sepfm_ros.fleet.slices import overlap_ns, plan_slices, warm_pairs
from sepfm_ros.ros.session.parameters import PARAMS


def _rosbag2(folder):
    folder.mkdir(parents=True)
    (folder / "metadata.yaml").write_text("rosbag2_bagfile_information: {}\n")
    (folder / "data_0.mcap").write_bytes(b"")  # storage inside a bag is not a bag of its own
    return folder


def test_find_bags_in_folders_globs_and_lists(tmp_path):
    a = _rosbag2(tmp_path / "robots" / "r1" / "monday")
    b = tmp_path / "robots" / "r2" / "run.bag"
    b.parent.mkdir(parents=True)
    b.write_bytes(b"")
    c = tmp_path / "loose" / "x.mcap"
    c.parent.mkdir()
    c.write_bytes(b"")
    (tmp_path / "loose" / "notes.md").write_text("not a bag")
    listing = tmp_path / "bags.txt"
    listing.write_text("# last week's\nloose/x.mcap\nrobots/r2/run.bag\nmissing.bag\n")
    found = find_bags([str(tmp_path / "robots"), str(listing), str(tmp_path / "robots/*/run.bag")])
    assert found.bags == sorted([a, b, c, tmp_path / "missing.bag"])  # each once
    assert found.notes == []
    empty = tmp_path / "empty"
    empty.mkdir()
    found = find_bags([str(empty), str(tmp_path / "nothing*")])
    assert found.bags == [] and len(found.notes) == 2, found.notes


def test_slices_cover_the_bag_once():
    start, end = 10**18, 10**18 + 95 * 10**8  # 9.5 s
    slices = plan_slices(start, end, 2.0)
    assert len(slices) == 5
    assert all(a < b for a, b in slices)
    assert all(s[1] == t[0] for s, t in zip(slices, slices[1:], strict=False))  # no gap
    assert slices[0][0] < start and slices[-1][1] > end
    assert plan_slices(start, end, 0.0) == plan_slices(start, end, 60.0)
    assert len(plan_slices(start, end, 0.0)) == 1
    params = {name: spec.default for name, spec in PARAMS.items()}
    # the overlap holds the window, the pairing queue and the frame gap, in frame periods
    frames = params["calibration_window"] + params["sync_queue_size"] + params["frame_gap"]
    assert overlap_ns(params, 10**8, 0) >= frames * 10**8
    # and the correction's window when it is the longer one (40 pairs against 10)
    assert warm_pairs(params) == max(params["calibration_window"], params["correction_window"])
    assert warm_pairs({**params, "correction_window": 40, "calibration_window": 10}) == 40


def test_rig_names_from_paths_and_conflicts():
    pattern = compile_pattern(r"robots/(?P<rig>[^/]+)/")
    assert rig_name(pattern, "/data/robots/r7/monday", "rig-1") == "r7"
    assert rig_name(pattern, "/data/elsewhere/x.bag", "rig-1") == "rig-1"
    assert rig_name(None, "/data/robots/r7/monday", "rig-1") == "rig-1"
    with pytest.raises(RigPatternError):
        compile_pattern("robots/(")
    warnings = naming_conflicts(
        [("r7", "rig-1", "a"), ("r7", "rig-2", "b"), ("r8", "rig-3", "c"), ("r9", "rig-3", "d")]
    )
    assert len(warnings) == 2
    assert "r7" in warnings[0] and "rig-1, rig-2" in warnings[0]
    assert "r8, r9" in warnings[1]


def _pair(k: int, rotation: float) -> PairRecord:
    return PairRecord(k, k, "ok", True, 100, 80, 0.3, rotation)


def test_drift_start_goes_back_over_the_drifted_pairs():
    rot = [0.02, 0.03, 0.02, 0.5, math.nan, 0.48, 0.51, 0.49, 0.5]
    pairs = [_pair(k, r) for k, r in enumerate(rot)]
    assert drift_start(pairs, 7, 0.07) == 3  # the NaN pair (too few inliers) is passed over
    assert drift_start(pairs, 1, 0.07) == 1  # a flag whose pair is not over: the flag itself


def test_ledger_one_row_per_bag_and_resume(tmp_path):
    out = tmp_path / "out"
    ledger = Ledger.open(out)
    row = BagRow("rig-1", "rig-1", "l + r", "/bags/a", "done", key="k1", pairs=2)
    ledger.write(row, [_pair(1, 0.02), _pair(2, 0.03)])
    with pytest.raises(DuplicateRowError):
        ledger.write(row, [_pair(1, 0.02)])
    # an interrupted run: pairs of bag b written, its row not
    with (out / PAIRS_CSV).open("a", newline="") as f:
        f.write("rig-2,/bags/b,5,5,ok,True,1,1,,,,,,\n")
    again = Ledger.open(out)
    assert again.done("/bags/a", "k1") and not again.done("/bags/a", "k2")
    assert not again.done("/bags/b", "k1")
    assert [p["bag"] for p in again.pairs()] == ["/bags/a", "/bags/a"]  # b's orphans dropped
    forced = Ledger.open(out, ["/bags/a"])
    assert not forced.done("/bags/a", "k1") and forced.pairs() == []
    with (out / BAGS_CSV).open() as f:
        assert list(csv.DictReader(f)) == []


def _info() -> BagInfo:
    return BagInfo("/bags/a", "stereo", ("/l", "/r"), True, (), 0, 10**9, 10**8, 0, 10, (10, 10))


def _corrected(k: int, level: str, pitch: float | None, reason: str = "") -> PairRecord:
    fix = {}
    if pitch is not None:
        fix = dict(correction_pitch_deg=pitch, correction_yaw_deg=0.0, correction_roll_deg=0.01,
                   correction_pitch_ci95_deg=0.004, correction_yaw_ci95_deg=0.06,
                   correction_roll_ci95_deg=0.01, correction_yaw_determined=False,
                   correction_pairs=k)  # fmt: skip
    return PairRecord(k, k, "ok", True, 100, 80, 0.3, 0.5, 1.0, 0.5, 0.5, level,
                      correction_reason=reason, **fix)  # fmt: skip


def test_flagged_bag_row_has_its_last_correction_a_held_one_none(tmp_path):
    th = Thresholds()
    pairs = [_corrected(k, "OK", None) for k in range(3)]
    pairs += [_corrected(3, "WARN", None, "too few pairs for a correction: 1 of 10")]
    pairs += [_corrected(k, "ERROR", 0.49 + k / 1000) for k in range(10, 13)]
    row = bag_row(_info(), pairs, "rig", "rig", "", "k", 1, th)
    assert row.correction_pitch_deg == pytest.approx(0.502) and row.correction_pairs == 12
    assert row.correction_reason == ""
    row = bag_row(_info(), pairs[:4], "rig", "rig", "", "k", 1, th)  # flagged, no correction
    assert math.isnan(row.correction_pitch_deg) and row.correction_pairs is None
    assert row.correction_reason == "too few pairs for a correction: 1 of 10"
    held = bag_row(_info(), pairs[:3], "rig", "rig", "", "k", 1, th)
    assert held.worst_level == "OK" and held.correction_reason == ""
    ledger = Ledger.open(tmp_path)
    ledger.write(held, pairs[:3])
    with (tmp_path / BAGS_CSV).open() as f:
        cells = next(csv.DictReader(f))
    assert all(cells[c] == "" for c in ROW_FIELDS if c.startswith("correction_")), cells
    assert all(v != "None" for v in ledger.rows["/bags/a"].values())


def test_a_ledger_written_before_the_correction_columns_reads(tmp_path):
    old = [c for c in ROW_FIELDS if not c.startswith("correction_")]
    with (tmp_path / BAGS_CSV).open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=old)
        w.writeheader()
        w.writerow({c: "" for c in old} | {"bag": "/bags/old", "state": "done", "key": "k0"})
    ledger = Ledger.open(tmp_path)
    assert ledger.done("/bags/old", "k0")
    with (tmp_path / BAGS_CSV).open() as f:
        rows = list(csv.DictReader(f))
    assert rows[0]["bag"] == "/bags/old" and rows[0]["correction_pitch_deg"] == ""


def _stream_no_ros():
    """test/stream's check that a package imports with ROS blocked (one copy of it)."""
    path = REPO_ROOT / "test" / "stream" / "test_stream_no_ros.py"
    spec = importlib.util.spec_from_file_location("stream_no_ros_check", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_every_fleet_module_imports_without_ros():
    """The fleet's parts run on any Python (the driver's machine needs no ROS to plan or
    report); the bag side is sepfm_ros.ros.offline.audit_slices."""
    r = _stream_no_ros().import_without_ros("sepfm_ros.fleet")
    assert r.returncode == 0, r.stdout + r.stderr
    imported = set(r.stdout.split())
    expected = {"discovery", "engine", "ledger", "records", "report", "rigs", "slices"}
    assert {f"sepfm_ros.fleet.{m}" for m in expected} <= imported
