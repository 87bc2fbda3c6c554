"""`sepfm_ros calibration_check BAG` on real bags: KITTI stereo, clean and decalibrated."""

from __future__ import annotations

import csv
import json
import signal
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
from rclpy.serialization import serialize_message
from sensor_msgs.msg import CameraInfo
from std_msgs.msg import Header

from sepfm_ros.geometry.calibrated.pose import pose_from_projections
from sepfm_ros.ros.bags.reader import BagReader, RawMessage
from sepfm_ros.ros.bags.writer import write_bag
from sepfm_ros.ros.msgs.image_conversion import numpy_to_image
from sepfm_ros.synthetic.sequences import stereo_sequence

REPO_ROOT = Path(__file__).resolve().parents[2]
FRAMES = 12
IMAGE = "sensor_msgs/msg/Image"
INFO = "sensor_msgs/msg/CameraInfo"


def _infos(shared_data) -> tuple[CameraInfo, CameraInfo]:
    """CameraInfo of KITTI's rectified left and right cameras (rig frame = left camera)."""
    cams = json.loads((shared_data / "cameras.json").read_text())
    K_a, K_b, _, t = pose_from_projections(
        np.array(cams["kitti_seq2/left/000000.png"]), np.array(cams["kitti_seq2/right/000000.png"])
    )
    out = []
    for K, P in ((K_a, K_a @ np.eye(3, 4)), (K_b, K_b @ np.c_[np.eye(3), t])):
        msg = CameraInfo(width=1241, height=376, distortion_model="plumb_bob", d=[0.0] * 5)
        msg.k = K.ravel().tolist()
        msg.r = np.eye(3).ravel().tolist()
        msg.p = P.ravel().tolist()
        out.append(msg)
    return out[0], out[1]


def _write_kitti_bag(
    shared_data,
    path,
    rotation_deg=(0.0, 0.0, 0.0),
    with_info=True,
    prefix="",
    lag_ns=0,
    right_frames=range(FRAMES),
) -> None:
    """KITTI's first FRAMES stereo frames at 10 Hz on ``{prefix}/left/image_raw`` and
    ``.../right/...``, camera_info beside them; the right stamps ``lag_ns`` after the left.
    ``right_frames``: the frame slots k that have a right image (slots from FRAMES on hold
    the last right image, without a left one)."""
    info_l, info_r = _infos(shared_data)
    K = np.reshape(info_r.k, (3, 3))
    H = K @ cv2.Rodrigues(np.radians(rotation_deg))[0] @ np.linalg.inv(K)
    msgs = []
    for k in range(max(FRAMES, max(right_frames) + 1)):
        for side, info, frame in (
            ("left", info_l, "left_camera_optical_frame"),
            ("right", info_r, "right_camera_optical_frame"),
        ):
            if k not in (right_frames if side == "right" else range(FRAMES)):
                continue
            stamp = 1_000_000_000 + k * 100_000_000 + (lag_ns if side == "right" else 0)
            img = cv2.imread(
                str(shared_data / f"kitti_seq2/{side}/{min(k, FRAMES - 1):06d}.png"),
                cv2.IMREAD_GRAYSCALE,
            )
            if side == "right":
                img = cv2.warpPerspective(img, H, (img.shape[1], img.shape[0]))
            header = Header(frame_id=frame)
            header.stamp.sec, header.stamp.nanosec = divmod(stamp, 1_000_000_000)
            msg = numpy_to_image(img, "mono8", header)
            topic = f"{prefix}/{side}/image_raw"
            msgs.append(RawMessage(topic, IMAGE, stamp, serialize_message(msg)))
            if with_info:
                info.header = header
                info_topic = f"{prefix}/{side}/camera_info"
                msgs.append(RawMessage(info_topic, INFO, stamp, serialize_message(info)))
    write_bag(path, msgs)


def _run(bag, out, *extra):
    return subprocess.run(
        [sys.executable, "-m", "sepfm_ros", "calibration_check", str(bag), "--out", str(out)]
        + list(extra),
        cwd=REPO_ROOT,
        capture_output=True,
        text=True,
        timeout=600,
    )


def _levels(out) -> list[str]:
    with (out / "calibration_check.csv").open() as f:
        return [row["level"] for row in csv.DictReader(f)]


@pytest.mark.parametrize(
    ("rotation", "expect_ok"), [((0.0, 0.0, 0.0), True), ((0.5, 0.0, 0.0), False)]
)
def test_clean_ok_and_rotated_warns(shared_data, tmp_path, rotation, expect_ok):
    bag = tmp_path / "kitti"
    _write_kitti_bag(shared_data, bag, rotation)
    out = tmp_path / "out"
    r = _run(bag, out)
    assert r.returncode == (0 if expect_ok else 1), r.stdout + r.stderr
    assert f"[{FRAMES}/{FRAMES}]" in r.stdout  # progress, one line per pair
    levels = _levels(out)
    assert len(levels) == FRAMES
    decided = [lv for lv in levels if lv != "STALE"]
    assert decided
    if expect_ok:
        assert set(decided) == {"OK"} and "decision: OK" in r.stdout
    else:
        assert set(decided) <= {"WARN", "ERROR"} and "decision: OK" not in r.stdout
    png = out / "calibration_check.png"
    assert png.stat().st_size > 10_000 and png.read_bytes()[:4] == b"\x89PNG"


def test_bag_without_camera_info_clear_error(shared_data, tmp_path):
    bag = tmp_path / "noinfo"
    _write_kitti_bag(shared_data, bag, with_info=False)
    r = _run(bag, tmp_path / "out")
    assert r.returncode == 2
    assert "no camera_info on /left/camera_info" in r.stderr
    assert not (tmp_path / "out").exists()


def test_robot_topic_names_and_a_lagging_right_camera(shared_data, tmp_path):
    """A rig's own topic names (picked from the bag, no --left/--right) and right stamps 12 ms
    after the left ones at 10 Hz: every frame pairs with its own right frame and the clean
    calibration is OK; a slop the user sets below the lag pairs nothing, which the error says."""
    bag = tmp_path / "rig"
    _write_kitti_bag(shared_data, bag, prefix="/rig/stereo", lag_ns=12_000_000)
    out = tmp_path / "out"
    r = _run(bag, out)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "/rig/stereo/left/image_raw + /rig/stereo/right/image_raw, picked" in r.stdout
    assert "/rig/stereo/left/camera_info" in r.stdout
    assert f"[{FRAMES}/{FRAMES}]" in r.stdout and "decision: OK" in r.stdout
    with (out / "calibration_check.csv").open() as f:
        stamps = [int(row["stamp_ns"]) for row in csv.DictReader(f)]
    assert stamps == [1_000_000_000 + k * 100_000_000 for k in range(FRAMES)]  # every left frame
    r = _run(bag, tmp_path / "out2", "-p", "sync_slop_s:=0.005")
    assert r.returncode == 2, r.stdout + r.stderr
    assert "no stereo pairs" in r.stderr and "sync_slop_s" in r.stderr, r.stderr
    assert "Traceback" not in r.stderr


def test_progress_counts_the_pairs_that_form(shared_data, tmp_path):
    """A right frame lost (slot 5) and one without a left partner (slot FRAMES): both cameras
    have FRAMES images but FRAMES - 1 pairs form; the progress counts those, not the messages,
    and the last line reads [FRAMES - 1/FRAMES - 1] (it read [FRAMES - 1/FRAMES])."""
    bag = tmp_path / "lost"
    right = [k for k in range(FRAMES + 1) if k != 5]
    _write_kitti_bag(shared_data, bag, right_frames=right)
    with BagReader(bag) as reader:
        counts = {t: i.count for t, i in reader.topics.items() if i.msgtype == IMAGE}
    assert counts == {"/left/image_raw": FRAMES, "/right/image_raw": FRAMES}
    out = tmp_path / "out"
    r = _run(bag, out)
    assert r.returncode == 0, r.stdout + r.stderr
    n = FRAMES - 1
    assert f"checking {n} stereo pairs" in r.stdout, r.stdout
    assert f"[{n}/{n}]" in r.stdout and "decision: OK" in r.stdout, r.stdout
    with (out / "calibration_check.csv").open() as f:
        stamps = [int(row["stamp_ns"]) for row in csv.DictReader(f)]
    assert stamps == [1_000_000_000 + k * 100_000_000 for k in range(FRAMES) if k != 5]
    r = _run(bag, tmp_path / "out2", "--max-pairs", "4", "-p", "calibration_min_pairs:=3")
    assert r.returncode == 0, r.stdout + r.stderr
    assert "checking 4 stereo pairs" in r.stdout and "[4/4]" in r.stdout, r.stdout
    assert "[5/" not in r.stdout


def test_motion_bag_says_stereo_is_needed(tmp_path):
    """A bag with one camera: calibration_check needs a stereo pair and says which flags
    choose one (not --image, which it does not take)."""
    bag = REPO_ROOT / "bags" / "synthetic_motion"
    r = _run(bag, tmp_path / "out")
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert "no two image topics whose names differ by left/right" in r.stderr
    assert "--left TOPIC --right TOPIC (stereo input is needed here)" in r.stderr
    assert "--image" not in r.stderr


def test_looped_bag_checks_every_pass(shared_data, tmp_path):
    """A recording of a looped replay (stamps jump back 1.1 s to the start): the pairing
    restarts as the node's does and every pass is checked, with a warning saying so."""
    once = tmp_path / "once"
    _write_kitti_bag(shared_data, once)
    with BagReader(once) as reader:
        msgs = list(reader.messages())
    span = 2 * FRAMES * 100_000_000
    looped = [RawMessage(m.topic, m.msgtype, m.log_time_ns + p * span, m.data) for p in (0, 1)
              for m in msgs]  # fmt: skip
    write_bag(tmp_path / "looped", looped)
    out = tmp_path / "out"
    r = _run(tmp_path / "looped", out)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "1 jump(s) back of over 1 s" in r.stdout, r.stdout
    assert f"[{2 * FRAMES}/{2 * FRAMES}]" in r.stdout and "decision: OK" in r.stdout
    with (out / "calibration_check.csv").open() as f:
        stamps = [int(row["stamp_ns"]) for row in csv.DictReader(f)]
    assert stamps == 2 * [1_000_000_000 + k * 100_000_000 for k in range(FRAMES)]


def test_sigint_stops_cleanly_between_pairs(shared_data, tmp_path):
    bag = tmp_path / "kitti"
    _write_kitti_bag(shared_data, bag)
    proc = subprocess.Popen(
        [sys.executable, "-m", "sepfm_ros", "calibration_check", str(bag), "--out",
         str(tmp_path / "out")],
        cwd=REPO_ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        for line in proc.stdout:
            if line.startswith(f"[2/{FRAMES}]"):
                proc.send_signal(signal.SIGINT)
                break
        out, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 130, err
    assert "calibration_check: interrupted" in err and "Traceback" not in err, err
    assert f"[{FRAMES}/{FRAMES}]" not in out


def _rig_infos(cam_a, cam_b) -> tuple[CameraInfo, CameraInfo]:
    """CameraInfo of a raw (unrectified) rig in the stereo_image_proc convention: the common
    rectified orientation is the left camera's, so R_a = I, R_b = R^T and P_b = K_a [I | R^T t]
    for the pose X_b = R X_a + t of the two synthetic cameras."""
    R = cam_b.R @ cam_a.R.T
    t = cam_b.t - R @ cam_a.t
    out = []
    for cam, R_rect, t_rect in ((cam_a, np.eye(3), np.zeros(3)), (cam_b, R.T, R.T @ t)):
        msg = CameraInfo(width=cam.size[0], height=cam.size[1], distortion_model="plumb_bob")
        msg.d = [0.0] * 5
        msg.k = np.asarray(cam.K, float).ravel().tolist()
        msg.r = R_rect.ravel().tolist()
        msg.p = (cam_a.K @ np.c_[np.eye(3), t_rect]).ravel().tolist()
        out.append(msg)
    return out[0], out[1]


def test_rig_of_two_cameras_of_different_sizes(tmp_path):
    """Left 480x360 and right 400x300 with their own K: each camera's camera_info is checked
    against its own image size, and the true calibration is OK."""
    frames = stereo_sequence(n_frames=8, right_size=(400, 300), seed=6)
    infos = _rig_infos(*frames[0].cameras)
    msgs = []
    for k, frame in enumerate(frames):
        stamp = 1_000_000_000 + k * 100_000_000
        for side, img, info in zip(("left", "right"), frame.images, infos, strict=True):
            header = Header(frame_id=f"{side}_optical_frame")
            header.stamp.sec, header.stamp.nanosec = divmod(stamp, 1_000_000_000)
            img_msg = serialize_message(numpy_to_image(img, "mono8", header))
            msgs.append(RawMessage(f"/{side}/image_raw", IMAGE, stamp, img_msg))
            info.header = header
            msgs.append(RawMessage(f"/{side}/camera_info", INFO, stamp, serialize_message(info)))
    write_bag(tmp_path / "rig", msgs)
    r = _run(tmp_path / "rig", tmp_path / "out")
    assert r.returncode == 0, r.stdout + r.stderr
    assert f"[{len(frames)}/{len(frames)}]" in r.stdout and "decision: OK" in r.stdout
    with (tmp_path / "out" / "calibration_check.csv").open() as f:
        medians = [float(row["epipolar_median_px"]) for row in csv.DictReader(f)]
    assert len(medians) == len(frames) and max(medians) < 1.0, medians
