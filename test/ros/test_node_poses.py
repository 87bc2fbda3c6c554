"""The live node's pose outputs over DDS, with camera_info: a calibrated KITTI stereo rig gives
~/relative_pose (PoseWithCovarianceStamped of the right camera in the left camera's optical
frame, the same pose as ~/relative_transform, with a positive-definite covariance); one moving
KITTI camera gives ~/angular_velocity (TwistWithCovarianceStamped) and ~/translation_direction
(unit Vector3Stamped) and no TransformStamped (whose parent would be its child)."""

from __future__ import annotations

import json
import threading
import time

import cv2
import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from geometry_msgs.msg import (  # noqa: E402
    PoseWithCovarianceStamped,
    TransformStamped,
    TwistWithCovarianceStamped,
    Vector3Stamped,
)
from ros_helpers import RELIABLE, header, image_msg, start_node  # noqa: E402
from sensor_msgs.msg import CameraInfo, Image  # noqa: E402

from sepfm_ros.ros.bags.synthesis import camera_info_message, camera_infos  # noqa: E402
from sepfm_ros.ros.msgs.headers import stamp_ns  # noqa: E402

T0 = 1_700_200_000 * 10**9
SIZE = (1241, 376)
TOPICS = {
    "relative_transform": TransformStamped,
    "relative_pose": PoseWithCovarianceStamped,
    "angular_velocity": TwistWithCovarianceStamped,
    "translation_direction": Vector3Stamped,
}


class PoseOutputs:
    """Every pose output of node ``name``, by topic kind and stamp."""

    def __init__(self, ros, name: str) -> None:
        self.lock = threading.Lock()
        self.got: dict[str, dict[int, object]] = {kind: {} for kind in TOPICS}
        for kind, msg_type in TOPICS.items():
            ros.node.create_subscription(msg_type, f"/{name}/{kind}", self._keep(kind), RELIABLE)

    def _keep(self, kind: str):
        def callback(msg):
            with self.lock:
                self.got[kind][stamp_ns(msg.header.stamp)] = msg

        return callback

    def wait(self, kind: str, stamp: int, timeout: float = 10.0):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            with self.lock:
                if stamp in self.got[kind]:
                    return self.got[kind][stamp]
            time.sleep(0.01)
        raise AssertionError(f"no {kind} for stamp {stamp}")


def _positive_definite(cov, n: int = 6) -> np.ndarray:
    C = np.asarray(cov, dtype=np.float64).reshape(n, n)
    assert np.allclose(C, C.T, rtol=0, atol=1e-12 * np.abs(C).max())
    assert np.all(np.linalg.eigvalsh(C) > 0), np.linalg.eigvalsh(C)
    return C


def _read(shared_data, path: str) -> np.ndarray:
    return cv2.imread(str(shared_data / path), cv2.IMREAD_GRAYSCALE)


def test_stereo_publishes_relative_pose_with_covariance(ros, tmp_path, shared_data):
    cams = json.loads((shared_data / "cameras.json").read_text())
    P = [np.asarray(cams[f"kitti_seq2/{s}/000000.png"]) for s in ("left", "right")]
    infos = camera_infos(tuple(P), SIZE)
    name, ns = "sepfm_poses_stereo", "/poses"
    proc, client = start_node(
        name,
        tmp_path,
        ros,
        {
            "left": (f"{ns}/left/image_raw", Image),
            "right": (f"{ns}/right/image_raw", Image),
            "left_info": (f"{ns}/left/camera_info", CameraInfo),
            "right_info": (f"{ns}/right/camera_info", CameraInfo),
        },
        "-r",
        f"left/image_raw:={ns}/left/image_raw",
        "-r",
        f"right/image_raw:={ns}/right/image_raw",
    )
    outputs = PoseOutputs(ros, name)
    time.sleep(0.5)  # the test's own subscriptions match
    try:
        for k in range(3):
            stamp = T0 + k * 100_000_000
            for key, calib, side in (
                ("left_info", infos[0], "left"),
                ("right_info", infos[1], "right"),
            ):
                hdr = header(stamp, f"{side}_camera_optical_frame")
                client.publish(key, camera_info_message(calib, SIZE, hdr))
            time.sleep(0.02)
            for side in ("left", "right"):
                client.publish(
                    side, image_msg(_read(shared_data, f"kitti_seq2/{side}/{k:06d}.png"), stamp)
                )
            values, _, _ = client.wait_outputs(stamp)
            assert values.pose_status == "ok"
            pose = outputs.wait("relative_pose", stamp)
            tf = outputs.wait("relative_transform", stamp)
            assert pose.header.frame_id == "left_camera_optical_frame"
            assert pose.header.stamp == values.header.stamp
            # the same pose as the transform: position and orientation
            p, t = pose.pose.pose.position, tf.transform.translation
            assert [p.x, p.y, p.z] == [t.x, t.y, t.z]
            assert pose.pose.pose.orientation == tf.transform.rotation
            C = _positive_definite(pose.pose.covariance)
            # the right camera is about one baseline (0.54 m) to the right: its position is
            # known to centimetres, its orientation to a fraction of a degree
            assert np.sqrt(C[0, 0]) < 0.05 and np.degrees(np.sqrt(np.max(np.diag(C)[3:]))) < 0.5
        with outputs.lock:
            assert not outputs.got["angular_velocity"] and not outputs.got["translation_direction"]
    finally:
        proc.stop()


def test_motion_publishes_angular_velocity_and_direction_and_no_transform(
    ros, tmp_path, shared_data
):
    cams = json.loads((shared_data / "cameras.json").read_text())
    (calib,) = camera_infos((np.asarray(cams["kitti_seq2/left/000000.png"]),), SIZE)
    name, ns = "sepfm_poses_motion", "/poses_motion"
    frame = "camera_optical_frame"
    proc, client = start_node(
        name,
        tmp_path,
        ros,
        {
            "image": (f"{ns}/camera/image_raw", Image),
            "info": (f"{ns}/camera/camera_info", CameraInfo),
        },
        "-p",
        "mode:=motion",
        "-r",
        f"image_raw:={ns}/camera/image_raw",
    )
    outputs = PoseOutputs(ros, name)
    time.sleep(0.5)
    dt = 0.1  # 10 Hz
    try:
        stamps = []
        for k in range(4):
            stamp = T0 + k * int(dt * 1e9)
            stamps.append(stamp)
            client.publish("info", camera_info_message(calib, SIZE, header(stamp, frame)))
            time.sleep(0.02)
            img = _read(shared_data, f"kitti_seq2/left/{k:06d}.png")
            client.publish("image", image_msg(img, stamp))
            if k > 0:
                client.wait_outputs(stamp)
        for stamp in stamps[1:]:
            values = client.wait_info(stamp)
            assert values.pose_status == "ok"
            twist = outputs.wait("angular_velocity", stamp)
            direction = outputs.wait("translation_direction", stamp)
            assert twist.header.frame_id == frame and direction.header.frame_id == frame
            w = twist.twist.twist.angular
            # |omega| dt is the rotation between the two frames
            rotation_deg = np.degrees(np.linalg.norm([w.x, w.y, w.z]) * dt)
            assert rotation_deg == pytest.approx(values.rotation_deg, abs=1e-4)  # arccos rounding
            C = _positive_definite(twist.twist.covariance)
            assert np.degrees(np.sqrt(np.max(np.diag(C)[3:]))) * dt < 0.5
            d = np.array([direction.vector.x, direction.vector.y, direction.vector.z])
            assert np.linalg.norm(d) == pytest.approx(1.0)
            assert d[2] > 0.9  # KITTI drives forward along the optical axis
        time.sleep(0.5)
        with outputs.lock:
            transforms = list(outputs.got["relative_transform"].values())
            poses = list(outputs.got["relative_pose"].values())
        assert not [tf for tf in transforms if tf.header.frame_id == tf.child_frame_id]
        assert not transforms and not poses
    finally:
        proc.stop()
