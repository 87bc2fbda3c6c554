"""The node's publishers and what it publishes for a pair (the messages of
:mod:`sepfm_ros.ros.session.answer`): ``~/estimate``, ``~/matches``, ``~/relative_transform``,
``~/calibration_check``, ``~/debug_image``, and the ``/diagnostics`` report. All reliable,
keep-last 10 (a consumer subscribed before the pair arrives gets every answer).

The answer publishers are lifecycle publishers: they publish only while the node is active.
:attr:`NodeOutputs.demand_publishers` lists the outputs whose subscribers are demand (the node
holds its image subscriptions only while one of them has a subscriber, unless ``always_on``):
a publisher added to that list counts. ``/diagnostics`` and ``~/calibration_check`` never
count."""

from __future__ import annotations

import time
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import TransformStamped
from rclpy.lifecycle import LifecycleNode
from rclpy.publisher import Publisher
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image
from std_msgs.msg import Header

from sepfm_msgs.msg import MatchArray, TwoViewEstimate
from sepfm_ros.pipeline.drawing import draw_result
from sepfm_ros.ros.msgs.diagnostics import diagnostic_array
from sepfm_ros.ros.msgs.image_conversion import numpy_to_image
from sepfm_ros.ros.session.answer import PairAnswer, add_timings

RELIABLE = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)


class NodeOutputs:
    """Publishers of the lifecycle node ``node`` (created here; ``diagnostics``: the node's
    ``/diagnostics`` publisher, which it holds in every state)."""

    def __init__(self, node: LifecycleNode, diagnostics: Publisher) -> None:
        make = node.create_lifecycle_publisher
        self.estimate = make(TwoViewEstimate, "~/estimate", RELIABLE)
        self.matches = make(MatchArray, "~/matches", RELIABLE)
        self.debug = make(Image, "~/debug_image", RELIABLE)
        self.diagnostics = diagnostics
        self.pose = make(TransformStamped, "~/relative_transform", RELIABLE)
        self.calibration = make(DiagnosticStatus, "~/calibration_check", RELIABLE)
        #: the outputs whose subscribers make the node work (see the module docstring)
        self.demand_publishers: list[Publisher] = [
            self.estimate,
            self.matches,
            self.pose,
            self.debug,
        ]
        self._node = node
        self._own = [self.estimate, self.matches, self.debug, self.pose, self.calibration]

    def demand(self) -> int:
        """Subscribers matched by the demand publishers (summed)."""
        return sum(p.get_subscription_count() for p in self.demand_publishers)

    def destroy(self) -> None:
        """Destroy the answer publishers (cleanup; ``/diagnostics`` stays)."""
        for pub in self._own:
            self._node.destroy_lifecycle_publisher(pub)

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
        if answer.transform is not None:
            self.pose.publish(answer.transform)
        if answer.calibration is not None:
            self.calibration.publish(answer.calibration)
        self.matches.publish(answer.matches)
        publish_ms = (time.perf_counter() - t0) * 1e3
        add_timings(answer.estimate, {"publish": publish_ms})
        self.estimate.publish(answer.estimate)
        result = answer.result
        if result is not None and images is not None and self.debug.get_subscription_count() > 0:
            canvas = draw_result(*images, result, epipolar_lines)
            self.debug.publish(numpy_to_image(canvas, "bgr8", answer.estimate.header))
        return publish_ms

    def report(self, stamp: Any, statuses: list[DiagnosticStatus]) -> None:
        """Publish ``statuses`` on /diagnostics under ``stamp``."""
        self.diagnostics.publish(diagnostic_array(Header(stamp=stamp, frame_id=""), statuses))

    def subscribers(self) -> dict[str, int]:
        """Matched subscribers: the fewest over the estimate and matches, and of
        ~/debug_image."""
        results = min(p.get_subscription_count() for p in (self.estimate, self.matches))
        return {
            "output_subscribers": results,
            "debug_image_subscribers": self.debug.get_subscription_count(),
        }
