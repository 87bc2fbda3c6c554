"""sepfm_msgs messages with every field set away from its default, their plain values, and (run as
a script) a publisher of them: the other process of the typed-message DDS test.

``python test/typed_msgs_sample.py ESTIMATE_TOPIC MATCHES_TOPIC`` publishes :func:`sample_estimate`
and :func:`sample_matches` every 0.2 s until SIGINT/SIGTERM, or for at most 120 s.

Import this module only after ``pytest.importorskip("sepfm_msgs.msg")``.
"""

from __future__ import annotations

import signal
import sys
import time
from typing import Any

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Quaternion, Transform, Vector3
from std_msgs.msg import Header

from sepfm_msgs.msg import Match, MatchArray, StageTiming, TwoViewEstimate
from sepfm_ros.ros.msgs.fundamental import fundamental_field

# F with distinct entries and F != F^T, so a transposed or scrambled copy cannot pass
SAMPLE_F = np.array(
    [[1.5e-7, -2.25e-6, 3.125e-4], [4.0625e-6, 5.5e-8, -6.75e-3], [-7.875e-4, 8.0e-3, 0.99995]]
)
PUBLISH_PERIOD_S = 0.2
MAX_RUN_S = 120.0


def sample_estimate() -> TwoViewEstimate:
    """A TwoViewEstimate whose every field (and every nested field) differs from its default."""
    return TwoViewEstimate(
        header=Header(stamp=Time(sec=1_700_000_123, nanosec=456_789_012), frame_id="left_optical"),
        stamp_a=Time(sec=1_700_000_123, nanosec=456_789_012),
        frame_id_a="left_optical",
        stamp_b=Time(sec=1_700_000_123, nanosec=456_789_013),
        frame_id_b="right_optical",
        width_a=1280,
        height_a=720,
        width_b=1281,
        height_b=721,
        has_f=True,
        f=fundamental_field(SAMPLE_F),
        status=TwoViewEstimate.STATUS_BAD_INPUT,
        status_text="bad input: size change",
        bad_input_kind="size_change",
        coordinates="rectified",
        method="sep4",
        features="sift",
        matches=812,
        inliers=544,
        inlier_error_px=0.4375,
        hypotheses=1234,
        stage1_hypotheses=321,
        stage2_hypotheses=913,
        samples=777,
        fallback=True,
        unfixed_lead=True,
        line_search_skipped=True,
        log10_nfa=-153.25,
        has_line_pair=True,
        line_a=np.array([0.6, 0.8, -412.5]),
        line_b=np.array([-0.8, 0.6, 97.25]),
        line_inliers=37,
        timings=[StageTiming(stage="features", ms=12.5), StageTiming(stage="total", ms=40.125)],
        pose_kind=TwoViewEstimate.POSE_METRIC,
        pose_status="ok",
        pose=Transform(
            translation=Vector3(x=-0.12, y=0.0025, z=0.001),
            rotation=Quaternion(x=0.01, y=-0.02, z=0.03, w=0.9993),
        ),
        rotation_deg=4.125,
        inliers_in_front=530,
    )


def sample_matches() -> MatchArray:
    """A MatchArray of two matches whose fields differ from their defaults."""
    estimate = sample_estimate()
    return MatchArray(
        header=estimate.header,
        stamp_a=estimate.stamp_a,
        stamp_b=estimate.stamp_b,
        matches=[
            Match(u_a=10.5, v_a=20.25, u_b=11.0, v_b=19.75, error_px=0.125, inlier=True),
            Match(u_a=400.0, v_a=300.5, u_b=390.25, v_b=301.0, error_px=7.5, on_line=True),
        ],
    )


def plain(value: Any) -> Any:
    """An rclpy message (or field value) as plain Python: dicts of fields, lists, scalars."""
    if hasattr(value, "get_fields_and_field_types"):
        return {name: plain(getattr(value, name)) for name in value.get_fields_and_field_types()}
    if isinstance(value, (list, tuple, np.ndarray)) or type(value).__name__ == "array":
        return [plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def _publish(estimate_topic: str, matches_topic: str) -> None:
    import rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    stop = []
    signal.signal(signal.SIGTERM, lambda *_: stop.append(True))
    rclpy.init()
    node = rclpy.create_node("sepfm_typed_msgs_publisher")
    qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    estimates = node.create_publisher(TwoViewEstimate, estimate_topic, qos)
    matches = node.create_publisher(MatchArray, matches_topic, qos)
    print("publishing", flush=True)
    deadline = time.monotonic() + MAX_RUN_S
    try:
        while not stop and time.monotonic() < deadline:
            estimates.publish(sample_estimate())
            matches.publish(sample_matches())
            time.sleep(PUBLISH_PERIOD_S)
    except KeyboardInterrupt:
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    _publish(sys.argv[1], sys.argv[2])
