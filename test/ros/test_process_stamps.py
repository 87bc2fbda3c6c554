"""``process`` on bags whose header stamps are irregular, as a robot's bags can be: a repeated or
reordered frame, a looped recording, a camera driver restarted mid-bag. The pairing is the
node's (:mod:`sepfm_ros.stream.pairing`): a frame not after its topic's newest is skipped, a jump
back restarts the pairing, and every pass of a looped bag is processed and read back on its own.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
from rclpy.serialization import serialize_message
from ros_helpers import image_msg

from sepfm_ros.demo import bundled_bags_dir
from sepfm_ros.evaluation.bags import load_bag_pairs
from sepfm_ros.ros.bags.reader import BagReader
from sepfm_ros.ros.bags.results import read_results
from sepfm_ros.ros.bags.types import IMAGE
from sepfm_ros.ros.bags.writer import BagWriter
from sepfm_ros.synthetic.sequences import motion_sequence

STEREO = bundled_bags_dir() / "synthetic_stereo"
BASE_NS = 1_700_000_000 * 10**9


def run_process(bag: Path, out: Path, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "sepfm_ros", "process", str(bag), "-o", str(out), "--quiet"]
        + ["-p", "seed:=0", *args],
        capture_output=True,
        text=True,
        timeout=300,
    )


def motion_bag(path: Path, frames: list[np.ndarray], stamps_s: list[float]) -> list[int]:
    """A motion bag of ``frames`` with these header stamps, logged every 0.1 s; the stamps (ns)."""
    stamps = [BASE_NS + int(round(s * 1e9)) for s in stamps_s]
    with BagWriter(path) as writer:
        writer.add_topic("/image_raw", IMAGE)
        for k, (img, stamp) in enumerate(zip(frames, stamps, strict=True)):
            log = BASE_NS + 100_000_000 * (k + 1)
            writer.write("/image_raw", log, serialize_message(image_msg(img, stamp)))
    return stamps


def looped_copy(src: Path, dst: Path, passes: int) -> int:
    """Write ``src``'s messages ``passes`` times, unchanged (header stamps jump back at each new
    pass) at increasing log times, as a recorder sees ``replay --loop``; messages per pass."""
    with BagReader(src) as reader:
        msgs = list(reader.messages())
        topics = {t: (i.msgtype, i.qos) for t, i in reader.topics.items()}
        span = reader.end_time_ns - reader.start_time_ns + 100_000_000
    with BagWriter(dst) as writer:
        for t, (msgtype, qos) in topics.items():
            writer.add_topic(t, msgtype, qos)
        for p in range(passes):
            for m in msgs:
                writer.write(m.topic, m.log_time_ns + p * span, m.data)
    return len(msgs)


def test_repeated_and_reordered_frames_are_skipped_as_the_node_skips_them(tmp_path):
    # a repeat (0.4), a step back (0.5 after 0.6), a gap (0.8 -> 2.3): the stamps of
    # test_robustness_bags' replay test, whose live node answers the same pairs
    stamps_s = [0.0, 0.2, 0.4, 0.4, 0.6, 0.5, 0.8, 2.3, 2.5, 2.7]
    frames = [f.images[0] for f in motion_sequence(n_frames=len(stamps_s), size=(320, 240))]
    stamps = motion_bag(tmp_path / "irregular", frames, stamps_s)
    res = run_process(tmp_path / "irregular", tmp_path / "out")
    assert res.returncode == 0, res.stderr
    assert "Traceback" not in res.stderr
    warning = [line for line in res.stderr.splitlines() if "warning" in line]
    assert len(warning) == 1, res.stderr
    assert "/image_raw: 2 frame(s) whose header stamp is not after the newest" in warning[0]
    assert "0 jump(s) back" in warning[0]
    accepted = [s for k, s in enumerate(stamps) if k == 0 or s > max(stamps[:k])]
    results = read_results(tmp_path / "out")
    assert [r.stamp_ns for r in results] == accepted[1:]
    assert all(r.run == 0 and r.F is not None for r in results)
    # the expected count is the pairing's, not the message count's: nothing reads as lost
    n = len(accepted) - 1
    assert f"{n}/{n} frame pairs with F" in res.stdout and f"{n} of {n} pairs" in res.stdout


def test_looped_stereo_bag_every_pass_processed_and_read_back_apart(tmp_path):
    looped = tmp_path / "looped"
    looped_copy(STEREO, looped, passes=3)
    once = run_process(STEREO, tmp_path / "once")
    assert once.returncode == 0, once.stderr
    res = run_process(looped, tmp_path / "out", "--table")
    assert res.returncode == 0, res.stderr
    assert "2 jump(s) back of over 1 s" in res.stderr, res.stderr
    first = read_results(tmp_path / "once")
    results = read_results(tmp_path / "out")
    assert len(first) >= 10
    assert [r.run for r in results] == [p for p in range(3) for _ in first]
    for p in range(3):
        passed = results[p * len(first) : (p + 1) * len(first)]
        assert [r.stamp_ns for r in passed] == [r.stamp_ns for r in first]
        for a, b in zip(first, passed, strict=True):  # the same images, the same seed
            assert a.matches == b.matches and a.inliers == b.inliers
            assert np.allclose(a.F, b.F) and b.F_gt is not None
            assert b.error_px < 1.0
    assert " #3 " in res.stdout  # the table marks later passes
    assert f"{len(results)}/{len(results)} frame pairs with F" in res.stdout
    # eval --bags reads both the input and the processed bag, one pair id per pass
    for bag in (looped, tmp_path / "out"):
        pairs, errors = load_bag_pairs(bag, tmp_path / "frames")
        assert not errors
        ids = [p.pair_id for p in pairs]
        assert len(ids) == len(results) == len(set(ids))


def test_restarted_driver_same_stamps_other_images_are_not_taken_from_the_cache(tmp_path):
    """A camera driver restarts and its stamps start again at the same values, on other
    images: the second run's results are those of its own images (the feature cache is keyed
    by run as well as stamp)."""
    n = 5
    stamps_s = [0.3 * k for k in range(n)]  # the restart jumps back 1.2 s
    run_a = [f.images[0] for f in motion_sequence(n_frames=n, size=(320, 240), seed=1)]
    run_b = [f.images[0] for f in motion_sequence(n_frames=n, size=(320, 240), seed=2)]
    motion_bag(tmp_path / "restarted", run_a + run_b, stamps_s + stamps_s)
    motion_bag(tmp_path / "second", run_b, stamps_s)
    for name in ("restarted", "second"):
        res = run_process(tmp_path / name, tmp_path / f"out_{name}")
        assert res.returncode == 0, res.stderr
    restarted = read_results(tmp_path / "out_restarted")
    second = read_results(tmp_path / "out_second")
    assert [r.run for r in restarted] == [0] * (n - 1) + [1] * (n - 1)
    for a, b in zip(restarted[n - 1 :], second, strict=True):
        assert a.stamp_ns == b.stamp_ns
        assert a.matches == b.matches and np.allclose(a.F, b.F)
        pa, pb = a.pts(), b.pts()
        assert np.array_equal(pa[0], pb[0]) and np.array_equal(pa[1], pb[1])
