"""The live node with camera_info: a calibrated KITTI stereo stream gives the rig's relative pose on
~/relative_transform and an OK calibration check; the same rig decalibrated (the right camera
turned by 1 degree) turns the check to WARN or worse; an unusable camera_info gives an ERROR
calibration status while F is still estimated. Without camera_info the node behaves as before
(the other live tests)."""

from __future__ import annotations

import json
import threading
import time

import cv2
import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus  # noqa: E402
from geometry_msgs.msg import TransformStamped  # noqa: E402
from ros_helpers import RELIABLE, header, image_msg, start_node  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402
from sensor_msgs.msg import CameraInfo, Image  # noqa: E402

from sepfm_msgs.msg import TwoViewEstimate  # noqa: E402
from sepfm_ros.geometry.calibrated.pose import pose_from_projections  # noqa: E402
from sepfm_ros.ros.bags.synthesis import camera_info_message, camera_infos  # noqa: E402
from sepfm_ros.ros.msgs.headers import stamp_ns  # noqa: E402

NS = "/cal"
NODE = "sepfm_calib"
FRAMES = [(f"kitti_seq2/left/{k:06d}.png", f"kitti_seq2/right/{k:06d}.png") for k in range(24)]
T0 = 1_700_100_000 * 10**9
LEVEL = {int.from_bytes(v, "little"): v for v in (DiagnosticStatus.OK, DiagnosticStatus.WARN)}


class Outputs:
    """~/relative_transform of the node by stamp, and its ~/calibration_check statuses in order
    with their header stamps (a DiagnosticArray stamped with the pair's header)."""

    def __init__(self, ros) -> None:
        self.lock = threading.Lock()
        self.pose: dict[int, TransformStamped] = {}
        self.checks: list[DiagnosticStatus] = []
        self.check_stamps: list[int] = []
        ros.node.create_subscription(
            TransformStamped, f"/{NODE}/relative_transform", self._on_pose, RELIABLE
        )
        ros.node.create_subscription(
            DiagnosticArray, f"/{NODE}/calibration_check", self._on_check, RELIABLE
        )

    def _on_pose(self, msg):
        with self.lock:
            self.pose[stamp_ns(msg.header.stamp)] = msg

    def _on_check(self, msg):
        with self.lock:
            self.checks.extend(msg.status)
            self.check_stamps.extend([stamp_ns(msg.header.stamp)] * len(msg.status))

    def wait_check(self, stamp: int, timeout: float = 5.0) -> DiagnosticStatus:
        """The calibration check stamped ``stamp`` (AssertionError when none arrives)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            with self.lock:
                if stamp in self.check_stamps:
                    return self.checks[self.check_stamps.index(stamp)]
            time.sleep(0.01)
        with self.lock:
            raise AssertionError(f"no check stamped {stamp}; stamps {self.check_stamps}")


def rig(shared_data):
    cams = json.loads((shared_data / "cameras.json").read_text())
    left, right = FRAMES[0]
    return np.asarray(cams[left]), np.asarray(cams[right])


def test_stereo_camera_info_gives_pose_and_calibration_check(ros, tmp_path, shared_data):
    P_l, P_r = rig(shared_data)
    size = (1241, 376)
    infos = camera_infos((P_l, P_r), size)
    proc, client = start_node(
        NODE,
        tmp_path,
        ros,
        {
            "left": (f"{NS}/left/image_raw", Image),
            "right": (f"{NS}/right/image_raw", Image),
            "left_info": (f"{NS}/left/camera_info", CameraInfo),
            "right_info": (f"{NS}/right/camera_info", CameraInfo),
        },
        "-r",
        f"left/image_raw:={NS}/left/image_raw",
        "-r",
        f"right/image_raw:={NS}/right/image_raw",
        "-p",
        "calibration_window:=6",
        "-p",
        "calibration_min_pairs:=3",
    )
    outputs = Outputs(ros)
    time.sleep(0.5)  # the test's own subscriptions match
    K_r = infos[1].K

    def send(k: int, warp: np.ndarray | None = None, bad_info: bool = False) -> int:
        left_path, right_path = FRAMES[k % len(FRAMES)]
        left = cv2.imread(str(shared_data / left_path), cv2.IMREAD_GRAYSCALE)
        right = cv2.imread(str(shared_data / right_path), cv2.IMREAD_GRAYSCALE)
        if warp is not None:
            right = cv2.warpPerspective(right, warp, size, flags=cv2.INTER_LINEAR)
        stamp = T0 + k * 100_000_000
        for key, calib, frame in (
            ("left_info", infos[0], "left"),
            ("right_info", infos[1], "right"),
        ):
            msg = camera_info_message(calib, size, header(stamp, f"{frame}_camera_optical_frame"))
            if bad_info:
                msg.k = [float("nan")] * 9
            client.publish(key, msg)
        time.sleep(0.02)  # camera_info before its images, as drivers publish them
        client.publish("left", image_msg(left, stamp))
        client.publish("right", image_msg(right, stamp))
        return stamp

    try:
        # 1. clean rig: pose of the right camera in the left one's frame, OK check
        _, _, R_gt, t_gt = pose_from_projections(P_l, P_r)
        expected_position = -R_gt.T @ t_gt  # right camera centre in the left camera's frame
        rotation_errors, direction_errors = [], []
        for k in range(8):
            stamp = send(k)
            values, F, _ = client.wait_outputs(stamp)
            assert values.coordinates == "undistorted" and values.pose_status == "ok"
            assert values.pose_kind == TwoViewEstimate.POSE_METRIC
            deadline = time.monotonic() + 5.0
            while stamp not in outputs.pose and time.monotonic() < deadline:
                time.sleep(0.01)
            outputs.wait_check(stamp)  # each pair's check carries the pair's stamp
            with outputs.lock:
                tf = outputs.pose[stamp]
            assert tf.header.frame_id == "left_camera_optical_frame"
            assert tf.child_frame_id == "right_camera_optical_frame"
            q = tf.transform.rotation
            angle = np.degrees(Rotation.from_quat([q.x, q.y, q.z, q.w]).magnitude())
            p = tf.transform.translation
            position = np.array([p.x, p.y, p.z])
            cos = position @ expected_position / np.linalg.norm(position)
            cos /= np.linalg.norm(expected_position)
            rotation_errors.append(angle)
            direction_errors.append(np.degrees(np.arccos(min(cos, 1.0))))
            # scaled by the calibrated baseline (metres)
            assert np.linalg.norm(position) == pytest.approx(np.linalg.norm(t_gt), rel=1e-6)
            # ~/estimate carries the same pose
            assert values.pose == tf.transform
            assert values.rotation_deg == pytest.approx(angle, abs=1e-6)
        # a stereo pose from F alone trades a little yaw for forward translation on a short
        # baseline (measured on these pairs: rotation 0.6-0.8 deg, direction 0.5-8 deg); stated
        # error: rotation median below 1 degree (max 2), direction median below 5 (max 10)
        print(f"rotation error deg {np.round(rotation_errors, 2)}")
        print(f"direction error deg {np.round(direction_errors, 2)}")
        assert np.median(rotation_errors) < 1.0 and max(rotation_errors) < 2.0
        assert np.median(direction_errors) < 5.0 and max(direction_errors) < 10.0
        with outputs.lock:
            last = outputs.checks[-1]
            assert outputs.check_stamps == sorted(outputs.pose), "one check per pair, by stamp"
        assert last.name == f"/{NODE}: calibration"
        assert last.level == DiagnosticStatus.OK, last.message
        health = client.latest_health(after=0.0)
        assert "input_publishers" in health
        # 2. the right camera turned by 1 degree about its x axis: WARN or ERROR
        R_bad = Rotation.from_rotvec([np.radians(1.0), 0.0, 0.0]).as_matrix()
        warp = K_r @ R_bad @ np.linalg.inv(K_r)
        levels = []
        for k in range(8, 20):
            stamp = send(k, warp)
            client.wait_outputs(stamp, need_f=False)
            levels.append(outputs.wait_check(stamp).level)
            if levels[-1] in (DiagnosticStatus.WARN, DiagnosticStatus.ERROR):
                break
        assert levels[-1] in (DiagnosticStatus.WARN, DiagnosticStatus.ERROR), levels
        assert len(levels) <= 8, f"flagged only after {len(levels)} decalibrated pairs"
        # 3. an unusable camera_info: ERROR calibration status, F still estimated without it
        stamp = send(20, bad_info=True)
        values, F, _ = client.wait_outputs(stamp)
        assert values.coordinates == "image" and F is not None
        assert values.pose_kind == TwoViewEstimate.POSE_NONE and values.pose_status
        last = outputs.wait_check(stamp)
        assert last.level == DiagnosticStatus.ERROR and "camera_info unusable" in last.message
        assert "camera_info unusable" in proc.output()
    finally:
        proc.stop()
