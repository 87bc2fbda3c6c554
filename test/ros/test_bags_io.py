"""Bag I/O: reading/writing with rosbags (mcap), kill safety, and bad input to the bag commands.

Bad input (truncated or corrupt bag, missing topic, unknown or wrong message type, existing
output; for ``replay --strict`` also stamps out of order or repeated) must give a clear message
and exit code 1, no traceback, and no output that cannot be read back (here: no output at all, or
the existing one untouched).
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from rclpy.serialization import serialize_message
from shell_jobs import as_background_job
from std_msgs.msg import Header, String

from sepfm_ros.demo import bundled_bags_dir
from sepfm_ros.ros.bags.errors import BagCorruptError, BagNotFoundError, OutputExistsError
from sepfm_ros.ros.bags.reader import BagReader, RawMessage
from sepfm_ros.ros.bags.results import read_results
from sepfm_ros.ros.bags.types import header_stamp_ns
from sepfm_ros.ros.bags.writer import BagWriter, write_bag
from sepfm_ros.ros.msgs.image_conversion import numpy_to_image

STEREO = bundled_bags_dir() / "synthetic_stereo"


def run_cli(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "sepfm_ros", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def _string(i: int) -> bytes:
    return serialize_message(String(data=f"m{i}"))


def _image(stamp_s: float, value: int = 0) -> bytes:
    h = Header(frame_id="camera")
    h.stamp.sec, h.stamp.nanosec = int(stamp_s), int(round((stamp_s % 1) * 1e9))
    img = np.full((48, 64), value, np.uint8)
    return serialize_message(numpy_to_image(img, "mono8", h))


# ---------------------------------------------------------------------- library


def test_writer_segments_survive_and_merge(tmp_path):
    out = tmp_path / "b"
    with BagWriter(out, flush_interval_s=None) as w:
        w.add_topic("/a", "std_msgs/msg/String")
        with BagReader(out) as r:  # readable (empty) from the start
            assert r.message_count == 0
        for i in range(7):
            w.write("/a", 1000 + i, _string(i))
            if i % 3 == 2:
                w.flush()
                with BagReader(out) as r:  # readable mid-run, holding what was flushed
                    assert r.message_count == i + 1
    files = sorted(p.name for p in out.iterdir())
    assert files == ["b_0.mcap", "metadata.yaml"]  # merged into one file
    with BagReader(out) as r:
        got = [m.data for m in r.messages()]
        assert r.topics["/a"].count == 7
    assert got == [_string(i) for i in range(7)]


def test_writer_never_leaves_a_folder_that_is_no_bag(tmp_path, monkeypatch):
    # a process dying after the folder was made but before its first metadata.yaml (SIGKILL in
    # the kill-safety test hit this window) must leave nothing under the output name
    def die(self):
        raise KeyboardInterrupt  # stands for the kill: nothing after this point runs

    out = tmp_path / "b"
    monkeypatch.setattr(BagWriter, "_write_metadata", die)
    with pytest.raises(KeyboardInterrupt):
        BagWriter(out, flush_interval_s=None)
    assert not out.exists()
    monkeypatch.undo()
    with BagWriter(out, flush_interval_s=None) as w:  # the name is still free
        w.add_topic("/a", "std_msgs/msg/String")
    with BagReader(out) as r:
        assert r.message_count == 0


def test_writer_removes_what_a_killed_writer_left(tmp_path):
    # a writer killed before the rename leaves its hidden folder; writing the name again removes
    # it, but never the folder of a writer that is still running
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    stale = tmp_path / f".b.creating-{dead.pid}-0123abcd"
    live = tmp_path / f".b.creating-{os.getpid()}-0123abcd"
    other = tmp_path / f".c.creating-{dead.pid}-0123abcd"
    for d in (stale, live, other):
        d.mkdir()
    with BagWriter(tmp_path / "b", flush_interval_s=None) as w:
        w.add_topic("/a", "std_msgs/msg/String")
    assert not stale.exists() and live.exists() and other.exists()


def test_header_stamp_from_cdr():
    assert header_stamp_ns(_image(12.25)) == 12_250_000_000


def test_reader_errors(tmp_path):
    with pytest.raises(BagNotFoundError):
        BagReader(tmp_path / "nope")
    (tmp_path / "empty_dir").mkdir()
    with pytest.raises(BagNotFoundError):
        BagReader(tmp_path / "empty_dir")
    bad = tmp_path / "bad"
    shutil.copytree(STEREO, bad)
    (bad / "metadata.yaml").write_text("rosbag2_bagfile_information: {version: 9}\n")
    with pytest.raises(BagCorruptError):
        BagReader(bad)
    with pytest.raises(OutputExistsError):
        BagWriter(STEREO)


# ---------------------------------------------------------------------- kill safety


def _count(bag: Path, topic: str) -> int:
    try:
        with BagReader(bag) as r:
            return r.topics[topic].count if topic in r.topics else 0
    except Exception:  # noqa: BLE001 - polling while the writer works
        return -1


@pytest.mark.parametrize(
    "sig, background",
    [(signal.SIGKILL, False), (signal.SIGINT, False), (signal.SIGINT, True)],
    ids=["SIGKILL", "SIGINT", "SIGINT-background"],
)
def test_process_interrupted_leaves_readable_bag(tmp_path, sig, background):
    out = tmp_path / "out"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "sepfm_ros",
            "process",
            str(STEREO),
            "-o",
            str(out),
            "--quiet",
            "-p",
            "seed:=3",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=as_background_job if background else None,
    )
    deadline = time.monotonic() + 60
    while _count(out, "/sepfm/estimate") < 3:  # the metadata is rewritten atomically
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline
        time.sleep(0.02)
    proc.send_signal(sig)
    try:
        _, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:  # the signal did not stop it
            proc.kill()
            proc.wait()
    assert "Traceback" not in err, err
    if sig == signal.SIGINT:
        assert proc.returncode == 130, err
    partial = read_results(out)
    assert 3 <= len(partial) < 12
    # every result computed before the kill is there, and is the one a full run computes
    full = {r.stamp_ns: r for r in read_results(_full_run(tmp_path))}
    for r in partial:
        np.testing.assert_array_equal(r.F, full[r.stamp_ns].F)
        assert np.array_equal(r.match_rows, full[r.stamp_ns].match_rows)
        ref = full[r.stamp_ns].estimate
        assert (r.estimate.status, r.estimate.inliers) == (ref.status, ref.inliers)
    assert [r.stamp_ns for r in partial] == sorted(full)[: len(partial)]


def _full_run(tmp_path: Path) -> Path:
    out = tmp_path / "full"
    res = run_cli("process", str(STEREO), "-o", str(out), "--quiet", "-p", "seed:=3")
    assert res.returncode == 0, res.stderr
    assert "12/12 frame pairs with F" in res.stdout
    return out


# ---------------------------------------------------------------------- bad input


@pytest.fixture()
def bad_bags(tmp_path) -> dict[str, Path]:
    bags = {}
    # truncated: the mcap file cut in half
    bags["truncated"] = tmp_path / "truncated"
    shutil.copytree(STEREO, bags["truncated"])
    mcap = next(bags["truncated"].glob("*.mcap"))
    os.truncate(mcap, mcap.stat().st_size // 2)
    # corrupt: chunk bytes overwritten in the middle (index and footer intact); the window is
    # longer than any message, so it overwrites at least one record header, never just pixels
    bags["corrupt"] = tmp_path / "corrupt"
    shutil.copytree(STEREO, bags["corrupt"])
    mcap = next(bags["corrupt"].glob("*.mcap"))
    data = bytearray(mcap.read_bytes())
    mid, window = len(data) // 2, 256 * 1024
    data[mid : mid + window] = b"\xff" * window
    mcap.write_bytes(bytes(data))
    # missing metadata.yaml
    bags["no_metadata"] = tmp_path / "no_metadata"
    shutil.copytree(STEREO, bags["no_metadata"])
    (bags["no_metadata"] / "metadata.yaml").unlink()
    # no image topic at all
    bags["missing_topic"] = tmp_path / "missing_topic"
    write_bag(bags["missing_topic"], [RawMessage("/chatter", "std_msgs/msg/String", 1, _string(0))])
    # wrong type on the image topic
    bags["wrong_type"] = tmp_path / "wrong_type"
    write_bag(bags["wrong_type"], [RawMessage("/image_raw", "std_msgs/msg/String", 1, _string(0))])
    # an unknown message type (definition stored in the bag, but not a Jazzy type)
    bags["unknown_type"] = tmp_path / "unknown_type"
    with BagWriter(bags["unknown_type"]) as w:
        w.add_topic(
            "/image_raw", "my_msgs/msg/Thing", msgdef="string data\n", rihs01="RIHS01_" + "0" * 64
        )
        w.write("/image_raw", 1, _string(0))
    # stamps repeated / out of order
    for name, stamps in (("repeated", [1.0, 1.2, 1.2, 1.4]), ("backwards", [1.0, 1.4, 1.2, 1.6])):
        bags[name] = tmp_path / name
        msgs = [
            RawMessage("/image_raw", "sensor_msgs/msg/Image", int(i * 1e8) + 1, _image(s, 10 * i))
            for i, s in enumerate(stamps)
        ]
        write_bag(bags[name], msgs)
    return bags


EXPECTED = {
    "truncated": "cannot read bag",
    "corrupt": "corrupt",
    "no_metadata": "not a rosbag2 bag",
    "missing_topic": "no input images",
    "wrong_type": "has type std_msgs/msg/String; expected sensor_msgs/msg/Image",
    "unknown_type": "my_msgs/msg/Thing",
}
# (repeated and backwards stamps are not bad input to process: it skips those frames as the
# node does, test_process_stamps; replay --strict refuses them)


@pytest.mark.parametrize("kind", sorted(EXPECTED))
def test_process_bad_input(kind, bad_bags, tmp_path):
    out = tmp_path / "out"
    res = run_cli("process", str(bad_bags[kind]), "-o", str(out), "--quiet")
    assert res.returncode == 1, (res.stdout, res.stderr)
    assert "Traceback" not in res.stderr
    assert "sepfm_ros process: error:" in res.stderr
    assert EXPECTED[kind] in res.stderr, res.stderr
    assert not out.exists()  # no half-written output


@pytest.mark.parametrize("kind", ["truncated", "corrupt", "unknown_type", "repeated", "backwards"])
def test_replay_bad_input(kind, bad_bags, ros_domain_id):
    # repeated/backwards stamps are played with a warning unless --strict (test_robustness_bags)
    strict = ["--strict"] if kind in ("repeated", "backwards") else []
    res = run_cli("replay", str(bad_bags[kind]), "--quiet", *strict)
    assert res.returncode == 1, (res.stdout, res.stderr)
    assert "Traceback" not in res.stderr
    assert "sepfm_ros replay: error:" in res.stderr


def test_replay_missing_topic(ros_domain_id):
    res = run_cli("replay", str(STEREO), "--topics", "/nope", "--quiet")
    assert res.returncode == 1 and "topic /nope is not in bag" in res.stderr
    assert "Traceback" not in res.stderr


def test_existing_output_is_refused_and_untouched(tmp_path):
    out = tmp_path / "exists"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    for args in (
        ("process", str(STEREO), "-o", str(out)),
        ("make_bag", "--synthetic", "stereo", "--frames", "2", "-o", str(out)),
        ("record", "-o", str(out), "/sepfm/estimate"),
    ):
        res = run_cli(*args)
        assert res.returncode == 1, (args, res.stderr)
        assert "exists already" in res.stderr and "Traceback" not in res.stderr
    assert [p.name for p in out.iterdir()] == ["keep.txt"]
    assert (out / "keep.txt").read_text() == "mine"


def test_make_bag_bad_folder(tmp_path):
    res = run_cli("make_bag", "--images", str(tmp_path / "none"), "-o", str(tmp_path / "o"))
    assert res.returncode == 1 and "image folder not found" in res.stderr
    assert not (tmp_path / "o").exists()
