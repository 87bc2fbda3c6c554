"""``process`` and ``calibration_check`` on bags recorded the way a robot records them (written
with rosbags in the test).

Real KITTI stereo frames under a robot's topic names (``/camera/left/image_raw``, a
``camera_info`` per camera, ``/tf``), in rosbag2 sqlite3, rosbag2 mcap and ROS 1 ``.bag``, with
and without a 12 ms right-camera lag: every format reads, the input topics are picked (or taken
from ``--left``/``--right``), and F is the one the same images give under the package's own topic
layout (``make_bag``).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from rclpy.serialization import serialize_message
from robot_bags import FORMATS, LEFT_TOPIC, RIGHT_TOPIC, bag_path, write_robot_bag
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore
from std_msgs.msg import Header

from sepfm_ros.evaluation import cli
from sepfm_ros.evaluation.bags import load_bag_pairs
from sepfm_ros.geometry import fundamental_from_cameras
from sepfm_ros.ros.bags.errors import (
    BagCorruptError,
    BagError,
    BagNotFoundError,
    TopicNotFoundError,
)
from sepfm_ros.ros.bags.inputs import detect_inputs
from sepfm_ros.ros.bags.reader import BagReader
from sepfm_ros.ros.bags.results import gt_error_px, read_results
from sepfm_ros.ros.bags.synthesis import SourceFrame, make_bag
from sepfm_ros.ros.bags.types import IMAGE, header_stamp_ns
from sepfm_ros.ros.bags.writer import BagWriter
from sepfm_ros.ros.msgs.image_conversion import numpy_to_image
from sepfm_ros.ros.offline.process import ProcessInputs, run_process
from sepfm_ros.ros.session.parameters import parse_params
from sepfm_ros.synthetic.sequences import pair_fundamental, stereo_sequence

REPO = Path(__file__).resolve().parents[2]
N_PAIRS = 4
LAG_NS = 12_000_000
PARAMS = ["seed:=3"]


@pytest.fixture(scope="module")
def kitti_frames(shared_data) -> list[tuple[np.ndarray, np.ndarray]]:
    folder = shared_data / "kitti_seq2"
    frames = []
    for i in range(N_PAIRS):
        left = cv2.imread(str(folder / "left" / f"{i:06d}.png"), cv2.IMREAD_GRAYSCALE)
        right = cv2.imread(str(folder / "right" / f"{i:06d}.png"), cv2.IMREAD_GRAYSCALE)
        assert left is not None and right is not None
        frames.append((left, right))
    return frames


@pytest.fixture(scope="module")
def reference_F(kitti_frames, tmp_path_factory) -> list[np.ndarray | None]:
    """F per pair from the same images in the package's own layout (make_bag, /left/image_raw)."""
    folder = tmp_path_factory.mktemp("reference")
    bag = folder / "bundled_layout"
    make_bag(bag, "stereo", [SourceFrame(None, f, None) for f in kitti_frames])
    with BagReader(bag) as reader:
        assert sorted(reader.topics) == ["/left/image_raw", "/right/image_raw"]
    out = folder / "out"
    done, total = run_process(bag, out, parse_params(PARAMS), progress=False)
    assert done == total == N_PAIRS
    results = read_results(out)
    assert sum(r.F is not None for r in results) >= N_PAIRS - 1
    return [r.F for r in results]


def _assert_same_F(results, reference) -> None:
    assert len(results) == len(reference) == N_PAIRS
    for r, ref in zip(results, reference, strict=True):
        if ref is None:
            assert r.F is None
        else:
            np.testing.assert_array_equal(r.F, ref)


@pytest.mark.parametrize("fmt", FORMATS)
def test_every_format_reads(fmt, kitti_frames, tmp_path):
    bag = write_robot_bag(bag_path(tmp_path, fmt), fmt, kitti_frames[:2], right_lag_ns=LAG_NS)
    with BagReader(bag) as reader:
        assert reader.is_ros1 == (fmt == "ros1")
        types = {t: (i.msgtype, i.count) for t, i in reader.topics.items()}
        assert types == {
            LEFT_TOPIC: ("sensor_msgs/msg/Image", 2),
            RIGHT_TOPIC: ("sensor_msgs/msg/Image", 2),
            "/camera/left/camera_info": ("sensor_msgs/msg/CameraInfo", 2),
            "/camera/right/camera_info": ("sensor_msgs/msg/CameraInfo", 2),
            "/tf": ("tf2_msgs/msg/TFMessage", 2),
        }
        msgs = list(reader.messages())
        # every message is ROS 2 CDR whatever the format (ROS 1 converted, Header.seq dropped)
        by_topic = {}
        for m in msgs:
            by_topic.setdefault(m.topic, []).append(m)
        right_stamps = [header_stamp_ns(m.data) for m in by_topic[RIGHT_TOPIC]]
        left_stamps = [header_stamp_ns(m.data) for m in by_topic[LEFT_TOPIC]]
        assert [r - s for r, s in zip(right_stamps, left_stamps, strict=True)] == [LAG_NS] * 2
        img = reader.deserialize(by_topic[LEFT_TOPIC][1])
        assert (img.height, img.width, img.encoding) == (*kitti_frames[1][0].shape, "mono8")
        assert np.array_equal(img.data.reshape(img.height, img.width), kitti_frames[1][0])
        info = reader.deserialize(by_topic["/camera/right/camera_info"][0])
        assert info.header.frame_id == "right_camera_optical_frame"
        assert info.p[3] == pytest.approx(-700.0 * 0.54) and info.k[0] == 700.0
        tf = reader.deserialize(by_topic["/tf"][0])
        assert tf.transforms[0].child_frame_id == "camera"
        assert tf.transforms[0].transform.translation.z == pytest.approx(1.2)


@pytest.mark.parametrize("lag_ns", [0, LAG_NS], ids=["synchronous", "right_lags_12ms"])
@pytest.mark.parametrize("fmt", FORMATS)
def test_process_picks_robot_topics_and_gives_the_bundled_F(
    fmt, lag_ns, kitti_frames, reference_F, tmp_path, capsys
):
    bag = write_robot_bag(bag_path(tmp_path, fmt), fmt, kitti_frames, right_lag_ns=lag_ns)
    out = tmp_path / "out"
    done, total = run_process(bag, out, parse_params(PARAMS), progress=False)
    assert done == total == N_PAIRS
    err = capsys.readouterr().err
    assert f"input stereo from {LEFT_TOPIC} + {RIGHT_TOPIC} (picked" in err
    results = read_results(out)
    _assert_same_F(results, reference_F)
    # outputs carry the left stamps
    with BagReader(bag) as reader:
        lefts = [header_stamp_ns(m.data) for m in reader.messages([LEFT_TOPIC])]
    assert [r.stamp_ns for r in results] == lefts


def test_right_lag_needs_more_than_the_nodes_default_slop(kitti_frames, tmp_path):
    # the node's 5 ms sync_slop_s pairs none of the lagging frames: process's default pairing
    # (nearest right within half a frame period) is what makes the test above pass; a slop that
    # pairs nothing is an error that says so, before any output exists
    bag = write_robot_bag(bag_path(tmp_path, "mcap"), "mcap", kitti_frames, right_lag_ns=LAG_NS)
    with pytest.raises(BagError, match="no stereo pairs: .* within 5.0 ms .* sync_slop_s"):
        run_process(
            bag, tmp_path / "out", parse_params(["sync_slop_s:=0.005"]),
            ProcessInputs(slop_given=True), progress=False,
        )  # fmt: skip
    assert not (tmp_path / "out").exists()


def test_process_cli_topic_flags_on_a_ros1_bag(kitti_frames, reference_F, tmp_path):
    bag = write_robot_bag(
        bag_path(tmp_path, "ros1"),
        "ros1",
        kitti_frames,
        right_lag_ns=LAG_NS,
        extra_image_topics=["/camera/center/image_raw"],
    )
    out = tmp_path / "out"
    res = subprocess.run(
        [sys.executable, "-m", "sepfm_ros", "process", str(bag), "-o", str(out), "--quiet"]
        + ["--left", LEFT_TOPIC, "--right", RIGHT_TOPIC, "-p", PARAMS[0]],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert res.returncode == 0, res.stderr
    assert "picked" not in res.stderr and "Traceback" not in res.stderr
    assert f"wrote {out}: {N_PAIRS} of {N_PAIRS} pairs" in res.stdout
    _assert_same_F(read_results(out), reference_F)


def test_ambiguous_image_topics_give_a_clear_error(kitti_frames, tmp_path):
    center = "/camera/center/image_raw"
    bag = write_robot_bag(
        bag_path(tmp_path, "mcap"), "mcap", kitti_frames[:2], extra_image_topics=[center]
    )
    out = tmp_path / "out"
    res = subprocess.run(
        [sys.executable, "-m", "sepfm_ros", "process", str(bag), "-o", str(out), "--quiet"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert res.returncode == 1 and "Traceback" not in res.stderr
    err = res.stderr
    assert "sepfm_ros process: error:" in err and "3 camera image topics" in err
    for topic in (LEFT_TOPIC, RIGHT_TOPIC, center):
        assert f"{topic} (sensor_msgs/msg/Image)" in err
    assert "--left TOPIC --right TOPIC" in err and "--image TOPIC" in err
    assert not out.exists()
    # the library picks what the flags or --mode make unambiguous, and refuses bad combinations
    with BagReader(bag) as reader:
        assert detect_inputs(reader, mode="stereo").topics == (LEFT_TOPIC, RIGHT_TOPIC)
        assert detect_inputs(reader, image=center).topics == (center,)
        with pytest.raises(TopicNotFoundError, match="3 camera image topics") as err:
            detect_inputs(reader, mode="motion")
        assert "--image TOPIC (motion input is needed here)" in str(err.value)
        assert "--left" not in str(err.value)  # a motion-only command takes no stereo flags
        with pytest.raises(TopicNotFoundError, match="/nope is not in bag"):
            detect_inputs(reader, left="/nope", right=RIGHT_TOPIC)


def test_eval_bags_takes_the_topic_flags(kitti_frames, shared_data, tmp_path):
    cams = json.loads((shared_data / "cameras.json").read_text())
    gt = [
        fundamental_from_cameras(
            np.array(cams[f"kitti_seq2/left/{i:06d}.png"]),
            np.array(cams[f"kitti_seq2/right/{i:06d}.png"]),
        )
        for i in range(N_PAIRS)
    ]
    bag = write_robot_bag(
        bag_path(tmp_path, "ros1"),
        "ros1",
        kitti_frames,
        right_lag_ns=LAG_NS,
        extra_image_topics=["/camera/center/image_raw"],
        ground_truth=[g / np.linalg.norm(g) for g in gt],
    )
    # three cameras: no pick, one error for the bag naming the flags
    pairs, errors = load_bag_pairs(bag, tmp_path / "frames")
    assert pairs == [] and len(errors) == 1 and "--left TOPIC --right TOPIC" in errors[0].message
    out = tmp_path / "out"
    argv = ["--bags", str(bag), "--left", LEFT_TOPIC, "--right", RIGHT_TOPIC, "--out", str(out),
            "--cache", str(tmp_path / "cache"), "--methods", "cv-ransac", "--seeds", "0",
            "--no-progress"]  # fmt: skip
    assert cli.main(argv) == 0
    rows = (out / "runs.csv").read_text().splitlines()[1:]
    assert len(rows) == N_PAIRS  # every lagging right frame paired with its left one


def test_bad_ros1_and_unknown_files_give_bag_errors(kitti_frames, tmp_path):
    bag = write_robot_bag(bag_path(tmp_path, "ros1"), "ros1", kitti_frames[:2])
    data = bag.read_bytes()
    cut = tmp_path / "cut.bag"
    cut.write_bytes(data[: len(data) // 2])
    garbage = tmp_path / "garbage.bag"
    garbage.write_bytes(b"#ROSBAG V2.0\n" + bytes(range(256)) * 8)
    other = tmp_path / "notes.txt"
    other.write_text("not a bag")
    for path in (cut, garbage):
        with pytest.raises(BagCorruptError, match=f"cannot read bag {path}"):
            BagReader(path)
    with pytest.raises(BagNotFoundError, match="is not a bag"):
        BagReader(other)
    res = subprocess.run(
        [sys.executable, "-m", "sepfm_ros", "process", str(cut), "-o", str(tmp_path / "o")],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert res.returncode == 1 and "Traceback" not in res.stderr
    assert "sepfm_ros process: error: cannot read bag" in res.stderr
    assert not (tmp_path / "o").exists()


def test_a_definition_rosbags_cannot_verify_does_not_lose_the_bag(kitti_frames, tmp_path):
    # a robot's custom message whose stored hash rosbags' AnyReader rejects: the bag still
    # reads (rosbag2 messages are CDR, read with the Jazzy types) and the images process
    ts = get_typestore(Stores.ROS2_JAZZY)
    bag = tmp_path / "custom"
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        cam = writer.add_connection("/front/image_raw", "sensor_msgs/msg/Image", typestore=ts)
        odd = writer.add_connection(
            "/robot/status",
            "my_msgs/msg/Status",
            msgdef="string data\n",
            rihs01="RIHS01_" + "1" * 64,
        )
        for k, (left, _) in enumerate(kitti_frames[:3]):
            stamp = 1_700_000_000 * 10**9 + k * 100_000_000
            Time, Header = ts.types["builtin_interfaces/msg/Time"], ts.types["std_msgs/msg/Header"]
            header = Header(stamp=Time(sec=stamp // 10**9, nanosec=stamp % 10**9), frame_id="cam")
            img = ts.types["sensor_msgs/msg/Image"](
                header=header, height=left.shape[0], width=left.shape[1], encoding="mono8",
                is_bigendian=0, step=left.shape[1], data=left.reshape(-1),
            )  # fmt: skip
            writer.write(cam, stamp, bytes(ts.serialize_cdr(img, "sensor_msgs/msg/Image")))
            writer.write(odd, stamp, b"\x00\x01\x00\x00\x03\x00\x00\x00ok\x00")
    with BagReader(bag) as reader:
        assert reader.topics["/robot/status"].msgtype == "my_msgs/msg/Status"
        spec = detect_inputs(reader)
    assert (spec.mode, spec.topics) == ("motion", ("/front/image_raw",))
    done, total = run_process(bag, tmp_path / "out", parse_params(PARAMS), progress=False)
    assert done == total == 2


def test_calibration_check_on_a_lagging_ros1_robot_bag(kitti_frames, shared_data, tmp_path):
    """calibration_check reads a robot's ROS 1 bag as process does: its topic names picked,
    the camera_info beside them, the right camera 12 ms late; KITTI's own calibration is OK."""
    from sepfm_ros.geometry.calibrated.pose import pose_from_projections

    cams = json.loads((shared_data / "cameras.json").read_text())
    K_a, _, _, t = pose_from_projections(
        np.array(cams["kitti_seq2/left/000000.png"]), np.array(cams["kitti_seq2/right/000000.png"])
    )
    bag = write_robot_bag(
        bag_path(tmp_path, "ros1"), "ros1", kitti_frames, right_lag_ns=LAG_NS, K=K_a,
        baseline_m=float(np.linalg.norm(t)),
    )  # fmt: skip
    out = tmp_path / "check"
    res = subprocess.run(
        [sys.executable, "-m", "sepfm_ros", "calibration_check", str(bag), "--out", str(out),
         "-p", "calibration_min_pairs:=2"],
        cwd=REPO, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert res.returncode == 0, res.stdout + res.stderr
    assert f"{LEFT_TOPIC} + {RIGHT_TOPIC}, picked" in res.stdout
    assert f"[{N_PAIRS}/{N_PAIRS}]" in res.stdout and "decision: OK" in res.stdout


def test_process_a_rig_of_two_different_cameras(tmp_path, capsys):
    """Left 480x360 and right 400x300, each with its own K (an RGB camera beside a mono one):
    every pair is processed, F accurate against the rig's cameras."""
    frames = stereo_sequence(n_frames=3, right_size=(400, 300), seed=5)
    bag = tmp_path / "rig"
    with BagWriter(bag) as writer:
        for side in ("left", "right"):
            writer.add_topic(f"/rig/{side}/image_raw", IMAGE)
        for k, frame in enumerate(frames):
            stamp = 1_000_000_000 + k * 100_000_000
            for side, img in zip(("left", "right"), frame.images, strict=True):
                header = Header(frame_id=f"{side}_optical_frame")
                header.stamp.sec, header.stamp.nanosec = divmod(stamp, 1_000_000_000)
                msg = serialize_message(numpy_to_image(img, "mono8", header))
                writer.write(f"/rig/{side}/image_raw", stamp, msg)
    done, total = run_process(bag, tmp_path / "out", parse_params(PARAMS), progress=False)
    assert done == total == len(frames)
    assert "skipping" not in capsys.readouterr().err
    results = read_results(tmp_path / "out")
    assert len(results) == len(frames)
    for r, frame in zip(results, frames, strict=True):
        assert r.status == "ok" and (r.estimate.width_b, r.estimate.height_b) == (400, 300)
        assert gt_error_px(r.F, pair_fundamental(*frame.cameras), *r.pts()) < 1.0
