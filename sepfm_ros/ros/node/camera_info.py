"""The node's optional ``camera_info`` inputs: which topics, and the message of each image.

Topics follow image_transport's camera subscriber: the ``camera_info`` beside the image topic,
after remaps and namespace (``-r left/image_raw:=/cam/left/image_raw`` listens to
``/cam/left/camera_info``), unless ``left/camera_info`` (``right/camera_info``, ``camera_info``)
is remapped itself.

Each image is matched to its camera's camera_info by stamp, as image_transport's camera
subscriber pairs them: the one of the same stamp, else the nearest within the sync slop
(``sync_slop_s``). The last ``KEPT`` messages of each camera are kept for it. An image without a
matching camera_info, once its camera has published one, is counted (``unmatched``) and answered
with its camera's latest camera_info (a camera whose calibration is constant republishes the same
one with every image, so the latest one still holds).
"""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Callable
from typing import Any

from rclpy.node import Node

from sepfm_ros.ros.msgs.headers import camera_info_topic, stamp_ns
from sepfm_ros.ros.node.keep_serving import ThrottledLog
from sepfm_ros.ros.node.subscriptions import InputSubscription

CAMERA_INFO = "camera_info"
KEPT = 30  # camera_info messages kept per camera (3 s of a 10 Hz camera)


def node_camera_info_topic(node: Node, image_base: str) -> str:
    """The camera_info topic a node follows for its image topic ``image_base`` (e.g.
    ``left/image_raw``): a remap of ``left/camera_info`` when the user gave one, else the topic
    beside the resolved image topic (:func:`~sepfm_ros.ros.msgs.headers.camera_info_topic`)."""
    own = image_base.rsplit("/", 1)[0] + "/" + CAMERA_INFO if "/" in image_base else CAMERA_INFO
    remapped = node.resolve_topic_name(own)
    if remapped != node.resolve_topic_name(own, only_expand=True):
        return remapped  # remapped by the user
    return camera_info_topic(node.resolve_topic_name(image_base))


def nearest_by_stamp(kept: list[tuple[int, Any]], stamp: int, slop_ns: int) -> Any | None:
    """The message of ``kept`` ((stamp ns, message) pairs) stamped ``stamp``, else the one of the
    nearest stamp within ``slop_ns`` (the newer of two as near), else None."""
    best: tuple[int, int] | None = None  # (|stamp difference|, index)
    for k, (t, _) in enumerate(kept):
        diff = abs(t - stamp)
        if diff <= slop_ns and (best is None or diff <= best[0]):
            best = (diff, k)
    return None if best is None else kept[best[1]][1]


class CameraInfoInputs:
    """The recent ``sensor_msgs/CameraInfo`` of each camera, matched to images by stamp
    (thread-safe).

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
        self._kept: list[deque[tuple[int, Any]]] = [deque(maxlen=KEPT) for _ in image_bases]
        self.received = 0
        self.unmatched = [0] * len(image_bases)  #: images answered without their camera_info
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
                self._kept[k].append((stamp_ns(msg.header.stamp), msg))
                self.received += 1

        return keep

    def latest(self) -> list[Any] | None:
        """The latest CameraInfo of every camera, or None while one has not arrived."""
        with self._lock:
            if any(not kept for kept in self._kept):
                return None
            return [kept[-1][1] for kept in self._kept]

    def for_stamps(self, stamps: list[int], slop_ns: int) -> tuple[list[Any] | None, list[int]]:
        """The CameraInfo of each camera for its image stamped ``stamps[k]`` (ns), matched as
        the module docstring says: (the messages, or None while a camera has published none;
        the cameras whose image had no matching camera_info, counted in ``unmatched``)."""
        with self._lock:
            if any(not kept for kept in self._kept):
                return None, []
            infos: list[Any] = []
            missing: list[int] = []
            for k, (kept, stamp) in enumerate(zip(self._kept, stamps, strict=True)):
                info = nearest_by_stamp(list(kept), stamp, slop_ns)
                if info is None:
                    missing.append(k)
                    self.unmatched[k] += 1
                    info = kept[-1][1]
                infos.append(info)
            return infos, missing

    def for_images(self, msgs: list[Any], slop_ns: int, log: ThrottledLog) -> list[Any] | None:
        """:meth:`for_stamps` for the images ``msgs`` (one per camera), logging (throttled by
        ``log``) each image answered without a camera_info of its stamp."""
        stamps = [stamp_ns(m.header.stamp) for m in msgs]
        infos, missing = self.for_stamps(stamps, slop_ns)
        for k in missing:
            log.log(
                "camera_info_unmatched",
                f"no camera_info on {self.topics[k]} stamped within sync_slop_s of the image "
                f"stamped {stamps[k] / 1e9:.3f} s: answered with the latest one",
                error=False,
            )
        return infos

    def diagnostic_values(self) -> dict[str, int]:
        """``camera_info_ready``: 1 once every camera's camera_info has arrived (a player can wait
        for it before the first images); ``images_without_camera_info``: images answered without
        a camera_info of their stamp (in all, and by camera_info topic)."""
        with self._lock:
            values = {
                "camera_info_ready": int(all(self._kept)),
                "images_without_camera_info": sum(self.unmatched),
            }
            if len(self.topics) > 1:
                for topic, count in zip(self.topics, self.unmatched, strict=True):
                    values[f"images_without_camera_info_{topic}"] = count
        return values


def calibration_in_use_text(calibration: Any) -> str:
    """The log line for a calibration newly in use (``calibration``: the session's
    :class:`~sepfm_ros.ros.session.calibrated.CalibratedStream` calibration)."""
    return (
        "camera_info in use: F in undistorted pixels of K"
        + (", rectified images" if calibration.rectified else "")
        + (f", no calibration check ({calibration.rig_problem})" if calibration.rig_problem else "")
        + ("" if calibration.rig is None else ", stereo calibration check on")
    )
