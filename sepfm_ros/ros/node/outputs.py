"""The node's publishers and what it publishes for a pair (the messages of
:mod:`sepfm_ros.ros.session.answer`): ``~/estimate``, ``~/matches``, the pose outputs
(``~/relative_transform`` and ``~/relative_pose`` of a stereo rig, ``~/angular_velocity`` and
``~/translation_direction`` of a moving camera), ``~/calibration_check``, ``~/debug_image`` with
its image_transport ``compressed`` companion ``~/debug_image/compressed`` (JPEG, format
``bgr8; jpeg compressed bgr8`` as image_transport's compressed publisher writes it), and the
``/diagnostics`` report. All reliable, keep-last 10 (a consumer subscribed before the pair
arrives gets every answer). The debug image is drawn, and encoded, only for subscribers of
either topic."""

from __future__ import annotations

import time
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import (
    PoseWithCovarianceStamped,
    TransformStamped,
    TwistWithCovarianceStamped,
    Vector3Stamped,
)
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CompressedImage, Image
from std_msgs.msg import Header

from sepfm_msgs.msg import MatchArray, TwoViewEstimate
from sepfm_ros.pipeline.drawing import draw_result
from sepfm_ros.ros.msgs.diagnostics import diagnostic_array
from sepfm_ros.ros.msgs.image_conversion import numpy_to_compressed, numpy_to_image
from sepfm_ros.ros.session.answer import PairAnswer, add_timings

#: CompressedImage.format of ~/debug_image/compressed (image_transport's compressed plugin)
DEBUG_COMPRESSED_FORMAT = "bgr8; jpeg compressed bgr8"


class NodeOutputs:
    """Publishers of the node ``node`` (created here)."""

    def __init__(self, node: Node) -> None:
        reliable = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self.estimate = node.create_publisher(TwoViewEstimate, "~/estimate", reliable)
        self.matches = node.create_publisher(MatchArray, "~/matches", reliable)
        self.debug = node.create_publisher(Image, "~/debug_image", reliable)
        self.debug_compressed = node.create_publisher(
            CompressedImage, "~/debug_image/compressed", reliable
        )
        self.diagnostics = node.create_publisher(DiagnosticArray, "/diagnostics", reliable)
        self.pose = node.create_publisher(TransformStamped, "~/relative_transform", reliable)
        self.relative_pose = node.create_publisher(
            PoseWithCovarianceStamped, "~/relative_pose", reliable
        )
        self.angular_velocity = node.create_publisher(
            TwistWithCovarianceStamped, "~/angular_velocity", reliable
        )
        self.translation_direction = node.create_publisher(
            Vector3Stamped, "~/translation_direction", reliable
        )
        self.calibration = node.create_publisher(DiagnosticArray, "~/calibration_check", reliable)

    def answer(
        self,
        answer: PairAnswer,
        images: tuple[np.ndarray, np.ndarray] | None = None,
        epipolar_lines: int = 0,
    ) -> float:
        """Publish one pair's messages: pose and calibration check (where there are ones),
        matches, then the estimate with the milliseconds spent publishing before it ("publish"
        stage, returned); the debug image last, drawn only for a subscriber (``images``: the
        decoded pair; none for a failure record)."""
        t0 = time.perf_counter()
        for publisher, msg in (
            (self.pose, answer.transform),
            (self.relative_pose, answer.relative_pose),
            (self.angular_velocity, answer.angular_velocity),
            (self.translation_direction, answer.translation_direction),
        ):
            if msg is not None:
                publisher.publish(msg)
        calibration_check = answer.calibration_check()
        if calibration_check is not None:
            self.calibration.publish(calibration_check)
        self.matches.publish(answer.matches)
        publish_ms = (time.perf_counter() - t0) * 1e3
        add_timings(answer.estimate, {"publish": publish_ms})
        self.estimate.publish(answer.estimate)
        result = answer.result
        raw = self.debug.get_subscription_count() > 0
        compressed = self.debug_compressed.get_subscription_count() > 0
        if result is not None and images is not None and (raw or compressed):
            canvas = draw_result(*images, result, epipolar_lines)
            header = answer.estimate.header
            if raw:
                self.debug.publish(numpy_to_image(canvas, "bgr8", header))
            if compressed:
                msg = numpy_to_compressed(canvas, "jpeg", header)
                msg.format = DEBUG_COMPRESSED_FORMAT
                self.debug_compressed.publish(msg)
        return publish_ms

    def report(self, stamp: Any, statuses: list[DiagnosticStatus]) -> None:
        """Publish ``statuses`` on /diagnostics under ``stamp``."""
        self.diagnostics.publish(diagnostic_array(Header(stamp=stamp, frame_id=""), statuses))

    def subscribers(self) -> dict[str, int]:
        """Matched subscribers: the fewest over the estimate and matches, and of
        ~/debug_image (raw and compressed together)."""
        results = min(p.get_subscription_count() for p in (self.estimate, self.matches))
        return {
            "output_subscribers": results,
            "debug_image_subscribers": self.debug.get_subscription_count()
            + self.debug_compressed.get_subscription_count(),
        }
