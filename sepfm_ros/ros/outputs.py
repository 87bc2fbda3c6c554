"""The node's publishers and what it publishes for a pair: F, matches, estimate info, debug image,
relative transform and calibration check, and the ``/diagnostics`` report. All reliable,
keep-last 10 (a consumer subscribed before the pair arrives gets every answer)."""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import TransformStamped
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image, PointCloud2
from std_msgs.msg import Header

from sepfm_ros.pipeline.drawing import draw_result
from sepfm_ros.pipeline.pipeline import PipelineResult
from sepfm_ros.ros.calibrated import CalibratedMessages
from sepfm_ros.ros.image_conversion import numpy_to_image
from sepfm_ros.ros.messages import (
    diagnostic_array,
    estimate_info,
    failure_info,
    fundamental_to_image,
    result_to_pointcloud2,
)


@dataclass
class Answer:
    """One answered pair: the result and what the outputs say about it."""

    result: PipelineResult
    header: Header  # the newer image's header (copied to every output)
    stamp_a: Any  # builtin_interfaces/Time of image a and b
    stamp_b: Any
    features: str
    publish_f: bool  # F is published (there is one, and ok or unreliable ones are wanted)
    timings_ms: Mapping[str, float]  # extra stages (wait, queue, latency, ...)
    values: Mapping[str, Any]  # extra ~/estimate_info values (pose, calibration)
    images: tuple[np.ndarray, np.ndarray]  # decoded a, b (for ~/debug_image)
    epipolar_lines: int


class NodeOutputs:
    """Publishers of the node ``node`` (created here)."""

    def __init__(self, node: Node) -> None:
        self._node_name = node.get_fully_qualified_name()
        reliable = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self.f = node.create_publisher(Image, "~/fundamental", reliable)
        self.matches = node.create_publisher(PointCloud2, "~/matches", reliable)
        self.info = node.create_publisher(DiagnosticArray, "~/estimate_info", reliable)
        self.debug = node.create_publisher(Image, "~/debug_image", reliable)
        self.diagnostics = node.create_publisher(DiagnosticArray, "/diagnostics", reliable)
        self.pose = node.create_publisher(TransformStamped, "~/relative_transform", reliable)
        self.calibration = node.create_publisher(DiagnosticStatus, "~/calibration_check", reliable)

    def answer(self, answer: Answer) -> float:
        """Publish one pair's outputs; returns the milliseconds spent before ~/estimate_info."""
        t0 = time.perf_counter()
        result, header = answer.result, answer.header
        if answer.publish_f:
            self.f.publish(fundamental_to_image(result.estimate.F, header))
        self.matches.publish(result_to_pointcloud2(result, header))
        publish_ms = (time.perf_counter() - t0) * 1e3
        self.info.publish(
            estimate_info(
                result,
                header,
                answer.stamp_a,
                answer.stamp_b,
                answer.features,
                extra_timings_ms={**answer.timings_ms, "publish": publish_ms},
                node_name=self._node_name,
                extra_values=answer.values,
            )
        )
        if self.debug.get_subscription_count() > 0:  # drawn only for a subscriber
            canvas = draw_result(*answer.images, result, answer.epipolar_lines)
            self.debug.publish(numpy_to_image(canvas, "bgr8", header))
        return publish_ms

    def calibrated(self, messages: CalibratedMessages) -> None:
        """The pair's relative transform and calibration check, where there are ones."""
        if messages.transform is not None:
            self.pose.publish(messages.transform)
        if messages.status is not None:
            self.calibration.publish(messages.status)

    def failure(
        self, header: Header, stamp_a: Any, stamp_b: Any, reason: str, kind: str, config: Any
    ) -> None:
        """Answer a pair that could not be processed on ~/estimate_info (ERROR level)."""
        self.info.publish(
            failure_info(
                header,
                stamp_a,
                stamp_b,
                reason,
                kind,
                config.features,
                config.method,
                node_name=self._node_name,
            )
        )

    def report(self, stamp: Any, statuses: list[DiagnosticStatus]) -> None:
        """Publish ``statuses`` on /diagnostics under ``stamp``."""
        self.diagnostics.publish(diagnostic_array(Header(stamp=stamp, frame_id=""), statuses))

    def subscribers(self) -> dict[str, int]:
        """Matched subscribers: the fewest over F, matches and info, and of ~/debug_image."""
        results = min(p.get_subscription_count() for p in (self.f, self.matches, self.info))
        return {
            "output_subscribers": results,
            "debug_image_subscribers": self.debug.get_subscription_count(),
        }
