"""``process`` on a robot's stereo bag with camera_info (written with rosbags alone): the relative
pose and the calibration check are written like the node publishes them; a rig whose right
camera turned by 1 degree is flagged; without camera_info no such topic is written."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from rclpy.serialization import deserialize_message
from robot_bags import bag_path, write_robot_bag
from sensor_msgs.msg import CameraInfo

from sepfm_msgs.msg import TwoViewEstimate
from sepfm_ros.geometry.calibrated.pose import pose_from_projections
from sepfm_ros.ros.bags.reader import BagReader
from sepfm_ros.ros.bags.results import read_calibration_checks, read_results
from sepfm_ros.ros.commands import make_bag
from sepfm_ros.ros.msgs.headers import stamp_ns
from sepfm_ros.ros.offline.process import run_process
from sepfm_ros.ros.session.parameters import parse_params

N = 8
TOPICS = ("/sepfm/relative_transform", "/sepfm/calibration_check")


@pytest.fixture(scope="module")
def kitti(shared_data):
    cams = json.loads((shared_data / "cameras.json").read_text())
    P_l = np.asarray(cams["kitti_seq2/left/000000.png"])
    P_r = np.asarray(cams["kitti_seq2/right/000000.png"])
    K, _, R, t = pose_from_projections(P_l, P_r)
    frames = []
    for i in range(N):
        pair = [
            cv2.imread(str(shared_data / f"kitti_seq2/{side}/{i:06d}.png"), cv2.IMREAD_GRAYSCALE)
            for side in ("left", "right")
        ]
        frames.append(tuple(pair))
    return K, float(np.linalg.norm(t)), frames


def _outputs(out):
    """The relative transforms and the calibration checks' statuses written to ``out``; the
    checks are stamped DiagnosticArrays, each with the stamp of a pair answered on
    ~/estimate."""
    from geometry_msgs.msg import TransformStamped

    with BagReader(out) as reader:
        poses = [
            deserialize_message(r.data, TransformStamped) for r in reader.messages([TOPICS[0]])
        ]
        assert reader.topics[TOPICS[1]].msgtype == "diagnostic_msgs/msg/DiagnosticArray"
    checks = read_calibration_checks(out)
    estimates = [stamp_ns(r.estimate.header.stamp) for r in read_results(out)]
    assert [c.stamp_ns for c in checks] == estimates  # one per pair, stamped with the pair's
    return poses, [c.status for c in checks]


def test_process_writes_pose_and_an_ok_check_for_a_calibrated_rig(kitti, tmp_path):
    K, baseline, frames = kitti
    bag = write_robot_bag(bag_path(tmp_path, "mcap"), "mcap", frames, K=K, baseline_m=baseline)
    done, total = run_process(bag, tmp_path / "out", parse_params([]), progress=False)
    assert done == total == N
    poses, checks = _outputs(tmp_path / "out")
    assert len(poses) >= N - 1 and len(checks) == N
    for tf in poses:
        assert tf.header.frame_id == "left_camera_optical_frame"
        assert tf.child_frame_id == "right_camera_optical_frame"
        p = tf.transform.translation
        # the right camera sits one calibrated baseline to the right (+x) of the left one
        assert np.linalg.norm([p.x, p.y, p.z]) == pytest.approx(baseline, rel=1e-6)
        assert p.x > 0.9 * baseline
    assert checks[-1].name == "/sepfm: calibration"  # the node the outputs are named for
    assert checks[-1].level == b"\x00", checks[-1].message  # OK
    # ~/estimate carries the same pose, metric, in undistorted pixels of K
    estimates = {
        stamp_ns(r.estimate.header.stamp): r.estimate for r in read_results(tmp_path / "out")
    }
    for tf in poses:
        est = estimates[stamp_ns(tf.header.stamp)]
        assert est.pose == tf.transform and est.pose_kind == TwoViewEstimate.POSE_METRIC
        assert est.coordinates == "undistorted" and est.pose_status == "ok"
    # ~/relative_pose: the same pose with a positive-definite covariance, stamped alike
    from geometry_msgs.msg import PoseWithCovarianceStamped

    with BagReader(tmp_path / "out") as reader:
        with_cov = {
            stamp_ns(m.header.stamp): m
            for m in (
                deserialize_message(r.data, PoseWithCovarianceStamped)
                for r in reader.messages(["/sepfm/relative_pose"])
            )
        }
    assert sorted(with_cov) == sorted(stamp_ns(tf.header.stamp) for tf in poses)
    for tf in poses:
        msg = with_cov[stamp_ns(tf.header.stamp)]
        assert msg.header.frame_id == tf.header.frame_id
        p = msg.pose.pose.position
        assert [p.x, p.y, p.z] == [
            tf.transform.translation.x,
            tf.transform.translation.y,
            tf.transform.translation.z,
        ]
        assert np.all(np.linalg.eigvalsh(np.reshape(msg.pose.covariance, (6, 6))) > 0)


def test_process_on_rectified_images_says_so(kitti, tmp_path):
    K, baseline, frames = kitti
    bag = write_robot_bag(bag_path(tmp_path, "mcap"), "mcap", frames[:2], K=K, baseline_m=baseline)
    run_process(bag, tmp_path / "out", parse_params(["images:=rectified"]), progress=False)
    results = read_results(tmp_path / "out")
    assert len(results) == 2
    for r in results:
        assert r.estimate.coordinates == "rectified" and r.F is not None


def test_process_flags_a_decalibrated_rig(kitti, tmp_path):
    K, baseline, frames = kitti
    R = cv2.Rodrigues(np.array([np.radians(1.0), 0.0, 0.0]))[0]
    H = K @ R @ np.linalg.inv(K)
    size = frames[0][1].shape[::-1]
    turned = [(left, cv2.warpPerspective(right, H, size)) for left, right in frames]
    bag = write_robot_bag(
        bag_path(tmp_path, "sqlite3"), "sqlite3", turned, K=K, baseline_m=baseline
    )
    run_process(bag, tmp_path / "out", parse_params([]), progress=False)
    _, checks = _outputs(tmp_path / "out")
    assert checks[-1].level in (b"\x01", b"\x02"), checks[-1].message  # WARN or ERROR


def test_without_camera_info_no_calibrated_topics(kitti, tmp_path):
    K, baseline, frames = kitti
    bag = write_robot_bag(bag_path(tmp_path, "mcap"), "mcap", frames[:3], K=K, baseline_m=baseline)
    out = tmp_path / "out"
    run_process(bag, out, parse_params(["use_camera_info:=false"]), progress=False)
    with BagReader(out) as reader:
        assert not set(TOPICS) & set(reader.topics)


def test_per_frame_camera_info_recomputed_to_rounding_is_one_calibration(shared_data, tmp_path):
    """KITTI's per-frame projection matrices (one camera_info per frame, as make_bag writes them)
    differ by 1e-7 of the focal length: one calibration, so the check's window fills and says
    OK rather than starting afresh at every pair."""
    bag = tmp_path / "kitti"
    args = ["--shared", "kitti_stereo", "--data", str(shared_data), "-o", str(bag), "--count", "8"]
    assert make_bag.main(args) == 0
    with BagReader(bag) as reader:
        fx = {
            deserialize_message(r.data, CameraInfo).p[0]
            for r in reader.messages(["/left/camera_info"])
        }
    assert len(fx) > 1  # the per-frame calibrations are not bit-equal
    done, total = run_process(bag, tmp_path / "out", parse_params([]), progress=False)
    assert done == total == 8
    _, checks = _outputs(tmp_path / "out")
    assert checks[-1].level == b"\x00", checks[-1].message  # OK


def test_process_motion_writes_angular_velocity_and_direction_not_a_transform(kitti, tmp_path):
    from geometry_msgs.msg import TwistWithCovarianceStamped, Vector3Stamped

    from sepfm_ros.ros.offline.process import ProcessInputs

    K, baseline, frames = kitti
    bag = write_robot_bag(bag_path(tmp_path, "mcap"), "mcap", frames[:4], K=K, baseline_m=baseline)
    choice = ProcessInputs(mode="motion", image="/camera/left/image_raw")
    done, _ = run_process(bag, tmp_path / "out", parse_params([]), choice, progress=False)
    assert done == 3
    with BagReader(tmp_path / "out") as reader:
        assert "/sepfm/relative_transform" not in reader.topics
        assert "/sepfm/relative_pose" not in reader.topics
        twists = [
            deserialize_message(r.data, TwistWithCovarianceStamped)
            for r in reader.messages(["/sepfm/angular_velocity"])
        ]
        directions = [
            deserialize_message(r.data, Vector3Stamped)
            for r in reader.messages(["/sepfm/translation_direction"])
        ]
    assert len(twists) == len(directions) == 3
    for twist, direction in zip(twists, directions, strict=True):
        assert twist.header.frame_id == direction.header.frame_id == "left_camera_optical_frame"
        assert np.all(np.linalg.eigvalsh(np.reshape(twist.twist.covariance, (6, 6))) > 0)
        d = direction.vector
        assert np.linalg.norm([d.x, d.y, d.z]) == pytest.approx(1.0)
        assert d.z > 0.9  # KITTI drives forward
