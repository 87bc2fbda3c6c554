"""The node's publishers and what it publishes for a pair (the messages of
:mod:`sepfm_ros.ros.session.answer`): ``~/estimate``, ``~/matches``, the pose outputs
(``~/relative_transform`` and ``~/relative_pose`` of a stereo rig, ``~/angular_velocity`` and
``~/translation_direction`` of a moving camera), ``~/calibration_check``, ``~/debug_image`` with
its image_transport ``compressed`` companion ``~/debug_image/compressed`` (JPEG, format
``bgr8; jpeg compressed bgr8`` as image_transport's compressed publisher writes it), and the
``/diagnostics`` report. All reliable, keep-last 10 (a consumer subscribed before the pair
arrives gets every answer). The debug image is drawn, and encoded, only for subscribers of
either topic.

The answer publishers are lifecycle publishers: they publish only while the node is active.
:attr:`NodeOutputs.demand_publishers` lists the outputs whose subscribers are demand (the node
holds its image subscriptions only while one of them has a subscriber, unless ``always_on``):
a publisher added to that list counts, and so do the corrected topics
(:mod:`~sepfm_ros.ros.node.corrected`). ``/diagnostics`` and ``~/calibration_check`` never
count."""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import (
    PoseWithCovarianceStamped,
    TransformStamped,
    TwistWithCovarianceStamped,
    Vector3Stamped,
)
from rclpy.lifecycle import LifecycleNode
from rclpy.publisher import Publisher
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CompressedImage, Image
from std_msgs.msg import Header

from sepfm_msgs.msg import MatchArray, TwoViewEstimate
from sepfm_ros.ros.msgs.diagnostics import diagnostic_array
from sepfm_ros.ros.msgs.image_conversion import numpy_to_compressed, numpy_to_image

if TYPE_CHECKING:  # created at configure: the pipeline's modules load after the graph start-up
    from sepfm_ros.ros.session.answer import PairAnswer

#: CompressedImage.format of ~/debug_image/compressed (image_transport's compressed plugin)
DEBUG_COMPRESSED_FORMAT = "bgr8; jpeg compressed bgr8"
RELIABLE = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)


class NodeOutputs:
    """Publishers of the lifecycle node ``node`` (created here; ``diagnostics``: the node's
    ``/diagnostics`` publisher, which it holds in every state)."""

    def __init__(self, node: LifecycleNode, diagnostics: Publisher) -> None:
        make = node.create_lifecycle_publisher
        self.estimate = make(TwoViewEstimate, "~/estimate", RELIABLE)
        self.matches = make(MatchArray, "~/matches", RELIABLE)
        self.debug = make(Image, "~/debug_image", RELIABLE)
        self.debug_compressed = make(CompressedImage, "~/debug_image/compressed", RELIABLE)
        self.diagnostics = diagnostics
        self.pose = make(TransformStamped, "~/relative_transform", RELIABLE)
        self.relative_pose = make(PoseWithCovarianceStamped, "~/relative_pose", RELIABLE)
        self.angular_velocity = make(TwistWithCovarianceStamped, "~/angular_velocity", RELIABLE)
        self.translation_direction = make(Vector3Stamped, "~/translation_direction", RELIABLE)
        self.calibration = make(DiagnosticArray, "~/calibration_check", RELIABLE)
        #: the outputs whose subscribers make the node work (see the module docstring)
        self.demand_publishers: list[Publisher] = [
            self.estimate,
            self.matches,
            self.pose,
            self.relative_pose,
            self.angular_velocity,
            self.translation_direction,
            self.debug,
            self.debug_compressed,
        ]
        self._node = node
        self._own = [*self.demand_publishers, self.calibration]

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
        from sepfm_ros.pipeline.drawing import draw_result
        from sepfm_ros.ros.session.answer import add_timings

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
