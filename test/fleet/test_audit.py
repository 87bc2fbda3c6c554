"""``sepfm_ros audit`` on a fleet of our own calibrated stereo bags, on real Dask clusters.

The fleet (``sepfm_ros.ros.bags.synthetic_fleet``): four rigs recording KITTI stereo with
camera_info, two bags each on two days; robot_b pitches by 0.5 degrees from frame 8 of its second
bag, robot_d from frame 12 of its first. Beside them a ROS 1 bag of a fifth rig, the package's
motion bag (no calibration: answer statistics only) and a truncated bag.
"""

from __future__ import annotations

import csv
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import cv2
import pytest
from robot_bags import write_robot_bag

from sepfm_ros.ros.bags.synthesis import camera_infos, shared_frames
from sepfm_ros.ros.bags.synthetic_fleet import RigPlan, make_fleet

pytestmark = pytest.mark.slow
distributed = pytest.importorskip("distributed", reason="the fleet extra: pip install distributed")

REPO_ROOT = Path(__file__).resolve().parents[2]
MOTION_BAG = REPO_ROOT / "bags" / "synthetic_motion"
RIGS = [
    RigPlan("robot_a"),
    RigPlan("robot_b", drift_from=(1, 8)),
    RigPlan("robot_c"),
    RigPlan("robot_d", drift_from=(0, 12)),
]
FRAMES = 20
PERIOD_S = 0.1
CORRECTION = [
    "correction_pitch_deg",
    "correction_yaw_deg",
    "correction_roll_deg",
    "correction_pitch_ci95_deg",
    "correction_yaw_ci95_deg",
    "correction_roll_ci95_deg",
    "correction_yaw_determined",
    "correction_pairs",
    "correction_reason",
]


def _audit(*args: str, timeout: float = 900) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "sepfm_ros", "audit", "--quiet", *args],
        cwd=REPO_ROOT,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def _rows(out: Path, name: str = "bags.csv") -> list[dict[str, str]]:
    with (out / name).open(newline="") as f:
        return list(csv.DictReader(f))


def _ros1_bag(shared_data: Path, path: Path) -> Path:
    """A fifth rig recorded as a robot does, in ROS 1 format, with KITTI's calibration."""
    _, frames = shared_frames(shared_data, "kitti_stereo")
    images = [tuple(cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in f.paths) for f in frames]
    h, w = images[0][0].shape
    calib = camera_infos(frames[0].cameras, (w, h))
    baseline = -calib[1].P[0, 3] / calib[1].P[0, 0]
    return write_robot_bag(path, "ros1", images[:FRAMES], K=calib[0].K, baseline_m=baseline)


@pytest.fixture(scope="module")
def fleet(shared_data, tmp_path_factory) -> tuple[Path, dict[str, list], Path]:
    """(folder of bags, bags of each rig, the truncated bag)."""
    root = tmp_path_factory.mktemp("fleet")
    bags = make_fleet(root / "bags", shared_data, RIGS, bags_per_rig=2, frames_per_bag=FRAMES)
    by_rig: dict[str, list] = {}
    for b in bags:
        by_rig.setdefault(b.rig, []).append(b)
    _ros1_bag(shared_data, root / "bags" / "day0" / "robot_e.bag")
    shutil.copytree(MOTION_BAG, root / "bags" / "motion")
    broken = root / "bags" / "day1" / "broken"
    shutil.copytree(by_rig["robot_a"][0].path, broken)
    storage = next(p for p in broken.iterdir() if p.name != "metadata.yaml")
    storage.write_bytes(storage.read_bytes()[: storage.stat().st_size // 3])
    return root / "bags", by_rig, broken


@pytest.fixture(scope="module")
def audited(fleet, tmp_path_factory) -> tuple[Path, subprocess.CompletedProcess]:
    out = tmp_path_factory.mktemp("audit") / "out"
    r = _audit(str(fleet[0]), "-o", str(out), "--workers", "2")
    return out, r


def test_report_flags_exactly_the_drifted_rigs_where_the_drift_starts(fleet, audited):
    bags_dir, by_rig, broken = fleet
    out, r = audited
    assert r.returncode == 1, r.stdout + r.stderr  # rigs flagged, a bag without an answer
    assert "Traceback" not in r.stderr, r.stderr
    rows = _rows(out)
    every = sorted(str(b.path) for bs in by_rig.values() for b in bs)
    every += [str(bags_dir / "day0" / "robot_e.bag"), str(bags_dir / "motion"), str(broken)]
    assert sorted(row["bag"] for row in rows) == sorted(every)  # one row per bag
    by_bag = {row["bag"]: row for row in rows}
    reason = by_bag[str(broken)]["reason"]
    assert by_bag[str(broken)]["state"] == "failed" and str(broken) in reason, reason
    assert "internal error" not in reason, reason
    # the same rig's bags group together across the day folders, and only they
    rig_of = {name: {by_bag[str(b.path)]["rig_id"] for b in bs} for name, bs in by_rig.items()}
    assert all(len(ids) == 1 for ids in rig_of.values()), rig_of
    assert len(set().union(*rig_of.values())) == len(RIGS)
    flagged = {row["rig_id"] for row in rows if row["worst_level"] in ("WARN", "ERROR")}
    assert flagged == rig_of["robot_b"] | rig_of["robot_d"]
    for plan in RIGS:
        for b in by_rig[plan.name]:
            row = by_bag[str(b.path)]
            assert row["state"] == "done" and row["calibrated"] == "True"
            assert int(row["pairs"]) == FRAMES and int(row["pairs_with_f"]) == FRAMES
            if b.drift_frame is not None:  # the bag where the drift starts: at its frame
                assert float(row["drift_start_s"]) == pytest.approx(
                    b.drift_frame * PERIOD_S, abs=PERIOD_S + 1e-6
                ), row
                assert float(row["first_flagged_s"]) >= float(row["drift_start_s"])
            if not b.drifted:
                assert row["worst_level"] == "OK" and row["first_flagged_s"] == "", row
                assert all(row[c] == "" for c in CORRECTION), row  # no correction columns
            else:
                _assert_corrected(row, FRAMES - (b.drift_frame or 0))
    # the first flag of each drifted rig is in the bag where its drift started
    for name in ("robot_b", "robot_d"):
        flags = [by_bag[str(b.path)] for b in by_rig[name]]
        first = min(
            (row for row in flags if row["first_flagged_utc"]),
            key=lambda row: row["first_flagged_utc"],
        )
        start = next(b for b in by_rig[name] if b.drift_frame is not None)
        assert first["bag"] == str(start.path)
    ros1 = by_bag[str(bags_dir / "day0" / "robot_e.bag")]
    assert ros1["state"] == "done" and ros1["worst_level"] == "OK", ros1
    motion = by_bag[str(bags_dir / "motion")]
    assert motion["state"] == "done" and motion["calibrated"] == "False"
    assert float(motion["share_with_f"]) > 0.5 and "ok" in motion["status_counts"], motion
    # the page: flagged rigs first, a PNG per rig
    report = (out / "report.md").read_text()
    first_ok = min(report.find(f"[{rid}]") for rid in rig_of["robot_a"] | rig_of["robot_c"])
    assert max(report.find(f"[{rid}]") for rid in flagged) < first_ok
    pngs = sorted((out / "plots").glob("*.png"))
    assert len(pngs) == len(RIGS) + 2 and all(p.read_bytes()[:4] == b"\x89PNG" for p in pngs)
    pairs = _rows(out, "pairs.csv")
    assert len(pairs) == sum(int(row["pairs"]) for row in rows)
    assert "| correction (deg) |" in report
    assert re.search(r"pitch [+-]0\.(4[789]|5[0123]).* pairs", report), report  # the knock


def _assert_corrected(row: dict[str, str], knocked_pairs: int) -> None:
    """A flagged bag's correction columns: the pitch knock (0.5 deg) with its interval when
    the bag ends with a correction; else the reason. A bag knocked for all its pairs has one."""
    if row["correction_pairs"] == "":
        assert knocked_pairs < FRAMES and row["correction_reason"], row
        assert row["correction_pitch_deg"] == "", row
        return
    assert 10 <= int(row["correction_pairs"]) <= knocked_pairs, row
    assert abs(abs(float(row["correction_pitch_deg"])) - 0.5) < 0.03, row
    assert 0 < float(row["correction_pitch_ci95_deg"]) < 0.1, row
    assert row["correction_yaw_determined"] in ("True", "False"), row


def test_rerun_skips_done_bags_and_force_redoes_them(fleet, audited):
    out, _ = audited
    before = _rows(out)
    r = _audit(str(fleet[0]), "-o", str(out), "--workers", "1")
    assert f"{len(before)} done in an earlier run" in r.stderr and "auditing 0 on" in r.stderr
    assert _rows(out) == before
    one = fleet[1]["robot_c"][0].path
    r = _audit(str(one), "-o", str(out), "--workers", "1", "--force")
    assert "auditing 1 on" in r.stderr, r.stderr
    after = _rows(out)
    assert sorted(row["bag"] for row in after) == sorted(row["bag"] for row in before)
    redone = next(row for row in after if row["bag"] == str(one))
    assert redone["key"] == next(row for row in before if row["bag"] == str(one))["key"]
    r = _audit(str(one), "-o", str(out), "--workers", "1", "-p", "seed:=3")
    assert "auditing 1 on" in r.stderr, r.stderr  # other parameters: a new key
    assert len(_rows(out)) == len(before)
    pairs = _rows(out, "pairs.csv")
    assert sum(p["bag"] == str(one) for p in pairs) == FRAMES


def test_slices_give_the_unsliced_answers(shared_data, tmp_path):
    """A 4 s bag whose rig pitches from frame 20, in one pass and in 5 slices of 0.8 s: the
    same pairs with the same answers and calibration decisions."""
    bags = make_fleet(tmp_path / "bags", shared_data, [RigPlan("long", drift_from=(0, 20))], 1, 40)
    runs = {}
    for slice_s in ("0", "0.8"):
        out = tmp_path / f"out_{slice_s}"
        r = _audit(str(bags[0].path), "-o", str(out), "--workers", "2", "--slice-s", slice_s)
        assert r.returncode == 1, r.stdout + r.stderr
        runs[slice_s] = (_rows(out), _rows(out, "pairs.csv"))
    assert runs["0"][0][0]["slices"] == "1" and runs["0.8"][0][0]["slices"] == "5"
    whole, sliced = runs["0"][1], runs["0.8"][1]
    assert len(whole) == 40
    assert sliced == whole  # every pair, every figure, every decision
    assert [p["level"] for p in whole].count("OK") >= 10  # the window spans slice boundaries
    assert {p["level"] for p in whole[30:]} <= {"WARN", "ERROR"}
    assert whole[-1]["correction_pairs"]  # the correction's window spans them too
    assert runs["0"][0][0]["correction_pitch_deg"] == runs["0.8"][0][0]["correction_pitch_deg"]


def _start(cmd: list[str], log: Path) -> subprocess.Popen:
    return subprocess.Popen(
        cmd, cwd=REPO_ROOT, stdout=log.open("w"), stderr=subprocess.STDOUT, start_new_session=True
    )


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGTERM)
        try:
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


def _wait_for(condition, timeout: float, what: str):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        time.sleep(0.2)
    raise AssertionError(f"timed out waiting for {what}")


def test_two_node_cluster_by_address_survives_a_killed_worker(fleet, tmp_path):
    """A scheduler and two worker processes started as on two machines (``dask scheduler``,
    ``dask worker ADDRESS``); the audit joins with --address. One worker is SIGKILLed while it
    runs an audit task: the task runs again and every bag still has exactly one row."""
    from distributed import Client

    dask = str(Path(sys.executable).parent / "dask")
    port_file = tmp_path / "scheduler.json"
    procs = [_start([dask, "scheduler", "--port", "0", "--no-dashboard",
                     "--scheduler-file", str(port_file)], tmp_path / "scheduler.log")]  # fmt: skip
    try:
        _wait_for(port_file.is_file, 60, "the scheduler")
        for k in range(2):
            procs.append(
                _start(
                    [
                        dask,
                        "worker",
                        "--scheduler-file",
                        str(port_file),
                        "--nthreads",
                        "1",
                        "--no-dashboard",
                    ],
                    tmp_path / f"worker{k}.log",
                )  # fmt: skip
            )
        client = Client(scheduler_file=str(port_file), timeout="30s")
        _wait_for(lambda: len(client.scheduler_info()["workers"]) == 2, 60, "two workers")
        address = client.scheduler.address
        days = [str(b.path) for bs in fleet[1].values() for b in bs]
        out = tmp_path / "out"
        audit = subprocess.Popen(
            [sys.executable, "-m", "sepfm_ros", "audit", "--quiet", "--address", address, "-o",
             str(out), *days],
            cwd=REPO_ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        try:

            def busy_worker():
                for worker, keys in client.processing().items():
                    if any("audit-slice" in str(k) for k in keys):
                        return worker, [k for k in keys if "audit-slice" in str(k)]
                return None

            worker, keys = _wait_for(busy_worker, 300, "an audit slice task on a worker")
            pid = client.run(os.getpid, workers=[worker])[worker]
            os.kill(pid, signal.SIGKILL)
            stdout, stderr = audit.communicate(timeout=900)
        finally:
            if audit.poll() is None:
                audit.kill()
                audit.wait()
        assert audit.returncode == 1, stdout + stderr  # flagged rigs, every bag answered
        rows = _rows(out)
        assert sorted(row["bag"] for row in rows) == sorted(days)  # exactly one row per bag
        assert all(row["state"] == "done" for row in rows), [r["reason"] for r in rows]
        assert len(_rows(out, "pairs.csv")) == FRAMES * len(days)
        # the killed worker's task ran again: the worker was replaced and the audit went on
        assert worker not in client.scheduler_info()["workers"]
        client.close()
    finally:
        for p in reversed(procs):
            _stop(p)
