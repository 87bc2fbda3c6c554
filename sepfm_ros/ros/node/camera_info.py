"""The node's optional ``camera_info`` inputs: which topics, and the latest message of each.

Topics follow image_transport's camera subscriber: the ``camera_info`` beside the image topic,
after remaps and namespace (``-r left/image_raw:=/cam/left/image_raw`` listens to
``/cam/left/camera_info``), unless ``left/camera_info`` (``right/camera_info``, ``camera_info``)
is remapped itself. The latest message of each camera is used while it does not change (a
camera's calibration is constant; drivers republish it with every image).
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

from rclpy.node import Node

from sepfm_ros.ros.msgs.headers import camera_info_topic
from sepfm_ros.ros.node.subscriptions import InputSubscription

CAMERA_INFO = "camera_info"


def node_camera_info_topic(node: Node, image_base: str) -> str:
    """The camera_info topic a node follows for its image topic ``image_base`` (e.g.
    ``left/image_raw``): a remap of ``left/camera_info`` when the user gave one, else the topic
    beside the resolved image topic (:func:`~sepfm_ros.ros.msgs.headers.camera_info_topic`)."""
    own = image_base.rsplit("/", 1)[0] + "/" + CAMERA_INFO if "/" in image_base else CAMERA_INFO
    remapped = node.resolve_topic_name(own)
    if remapped != node.resolve_topic_name(own, only_expand=True):
        return remapped  # remapped by the user
    return camera_info_topic(node.resolve_topic_name(image_base))


class CameraInfoInputs:
    """The latest ``sensor_msgs/CameraInfo`` of each camera (thread-safe).

    Args:
        node: the node that subscribes.
        image_bases: the image topics whose camera_info to follow (one per camera).
        reliability: QoS reliability choice (see :mod:`sepfm_ros.ros.node.subscriptions`).
        on_lost, on_incompatible, on_created: the subscription event callbacks.
    """

    def __init__(
        self,
        node: Node,
        image_bases: list[str],
        reliability: str,
        on_lost: Callable[[str, int], None],
        on_incompatible: Callable[[str, str], None],
        on_created: Callable[[str, str], None],
    ) -> None:
        from sensor_msgs.msg import CameraInfo

        self._lock = threading.Lock()
        self._latest: list[Any] = [None] * len(image_bases)
        self.received = 0
        self.topics = [node_camera_info_topic(node, base) for base in image_bases]
        self._make = lambda k, topic: InputSubscription(
            node,
            topic,
            CameraInfo,
            self._keeper(k),
            reliability,
            on_lost=on_lost,
            on_incompatible=on_incompatible,
            on_created=on_created,
        )
        self._subs: list[InputSubscription] = []
        self.resume()

    def resume(self) -> None:
        """Subscribe (again, after :meth:`pause`; the latest messages are kept)."""
        if not self._subs:
            self._subs = [self._make(k, topic) for k, topic in enumerate(self.topics)]

    def pause(self) -> None:
        """Destroy the subscriptions (the node has no demand, or is deactivated)."""
        for sub in self._subs:
            sub.destroy()
        self._subs = []

    def _keeper(self, k: int) -> Callable[[Any], None]:
        def keep(msg: Any) -> None:
            with self._lock:
                self._latest[k] = msg
                self.received += 1

        return keep

    def latest(self) -> list[Any] | None:
        """The latest CameraInfo of every camera, or None while one has not arrived."""
        with self._lock:
            if any(m is None for m in self._latest):
                return None
            return list(self._latest)
