"""Output message builders: F image, matches cloud, estimate info (pure functions, no DDS)."""

from __future__ import annotations

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import Image, PointCloud2
from std_msgs.msg import Header

from sepfm_ros.geometry import Estimate
from sepfm_ros.pipeline.features import Matches
from sepfm_ros.pipeline.pipeline import PipelineResult
from sepfm_ros.ros.messages import (
    ESTIMATE_STATUS_NAME,
    estimate_info,
    fundamental_from_image,
    fundamental_to_image,
    matches_from_pointcloud2,
    result_to_pointcloud2,
    status_values,
)

HEADER = Header(stamp=Time(sec=12, nanosec=345), frame_id="left_cam")


def make_result(with_f: bool = True) -> PipelineResult:
    rng = np.random.default_rng(0)
    pts_a, pts_b = rng.uniform(0, 600, (5, 2)), rng.uniform(0, 400, (5, 2))
    F = np.arange(9, dtype=np.float64).reshape(3, 3)
    F /= np.linalg.norm(F)
    est = Estimate(
        F=F if with_f else None,
        inliers=np.array([True, False, True, True, False]),
        hypotheses=17,
        stage1_hypotheses=5,
        stage2_hypotheses=12,
        line_pair=((0.0, 1.0, -10.0), (0.6, 0.8, -3.0)) if with_f else None,
        line_inliers=np.array([0, 2]),
        status="ok" if with_f else "no model",
        method="sep5",
    )
    errors = rng.uniform(0, 3, 5) if with_f else np.full(5, np.nan)
    on_line = np.array([True, False, True, False, False])
    timings = {"features": 3.0, "match": 1.5, "total": 9.0}
    return PipelineResult(
        Matches(pts_a, pts_b, np.linspace(0.1, 0.5, 5)), est, errors, on_line, (640, 480),
        (640, 480), timings,
    )  # fmt: skip


def test_fundamental_image_round_trip_through_cdr():
    F = make_result().estimate.F
    msg = deserialize_message(serialize_message(fundamental_to_image(F, HEADER)), Image)
    assert (msg.encoding, msg.height, msg.width, msg.step) == ("64FC1", 3, 3, 24)
    assert msg.header.frame_id == "left_cam" and msg.header.stamp.nanosec == 345
    np.testing.assert_array_equal(fundamental_from_image(msg), F)


def test_fundamental_image_rejects_bad_f():
    with pytest.raises(ValueError):
        fundamental_to_image(np.full((3, 3), np.nan), HEADER)
    with pytest.raises(ValueError):
        fundamental_to_image(np.eye(2), HEADER)


def test_matches_cloud_fields_and_round_trip():
    result = make_result()
    msg = deserialize_message(serialize_message(result_to_pointcloud2(result, HEADER)), PointCloud2)
    assert [f.name for f in msg.fields] == [
        "u_a",
        "v_a",
        "u_b",
        "v_b",
        "error",
        "inlier",
        "on_line",
    ]
    assert msg.width == 5 and msg.height == 1 and msg.point_step == 24
    cloud = matches_from_pointcloud2(msg)
    np.testing.assert_allclose(cloud["u_a"], result.matches.pts_a[:, 0].astype(np.float32))
    np.testing.assert_allclose(cloud["v_b"], result.matches.pts_b[:, 1].astype(np.float32))
    np.testing.assert_allclose(cloud["error"], result.errors.astype(np.float32))
    np.testing.assert_array_equal(cloud["inlier"], result.estimate.inliers)
    np.testing.assert_array_equal(cloud["on_line"], result.on_line)


def test_estimate_info_values():
    result = make_result()
    array = estimate_info(
        result, HEADER, Time(sec=12, nanosec=345), Time(sec=12, nanosec=999), "orb",
        extra_timings_ms={"decode": 0.5, "publish": 0.2},
    )  # fmt: skip
    (status,) = array.status
    assert status.name == ESTIMATE_STATUS_NAME and status.level == DiagnosticStatus.OK
    values = status_values(status)
    assert values["stamp_a"] == "12.000000345" and values["stamp_b"] == "12.000000999"
    assert values["matches"] == "5" and values["inliers"] == "3"
    assert values["stage1_hypotheses"] == "5" and values["stage2_hypotheses"] == "12"
    assert values["line_a"] == "0 1 -10" and values["line_b"] == "0.6 0.8 -3"
    assert values["ms_decode"] == "0.5" and values["ms_features"] == "3"
    assert array.header.frame_id == "left_cam"


def test_estimate_info_failure_is_warn_with_reason():
    result = make_result(with_f=False)
    (status,) = estimate_info(result, HEADER, HEADER.stamp, HEADER.stamp, "orb").status
    assert status.level == DiagnosticStatus.WARN and status.message == "no model"
    assert status_values(status)["line_a"] == "none"
