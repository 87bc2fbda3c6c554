"""The live node's corrected calibration of a knocked stereo rig: the corrected topics a stereo
pipeline subscribes to, and the correction sent to the camera drivers.

While the calibration check has a correction in force (the session's
:meth:`~sepfm_ros.pipeline.calibration.StreamCalibration.corrected_models`: the rig's K and D
as received, R and P of a new rectification from the corrected rotation of the right camera):

- ``publish_corrected:=true`` (:class:`CorrectedTopics`): every stereo pair the node forms is
  published again, each image unchanged on ``~/corrected/<side>/image_raw`` with the corrected
  ``sensor_msgs/CameraInfo`` on ``~/corrected/<side>/camera_info``, all four under the input
  image's own header (stamp and frame id), so image_transport's CameraSubscriber and
  stereo_image_proc pair them by exact stamp. Pairs are republished when they form, on the
  executor, whether or not the estimator later takes them (it works on the newest pair and
  drops older ones when busy): the corrected stream has the input's rate. An image without a
  partner of its stamp is not republished (a stereo consumer cannot use it). Subscribers to
  these topics are demand (the node must keep estimating to keep the correction current). With
  no correction in force nothing is published there; the ``calibration`` status says why.
- ``apply_correction:=true`` (:class:`CorrectionSender`): each new correction (one that comes
  into force; it stays until the calibration check clears or the camera_info changes) is sent
  once to each camera driver's ``set_camera_info`` service (``sensor_msgs/srv/SetCameraInfo``,
  as camera_calibration sends a calibration), asynchronously from the executor; a driver that
  stores it then publishes the corrected camera_info, which is a new calibration for the check.
  A side whose call fails (no service, no answer within :data:`APPLY_TIMEOUT_S`, or
  ``success`` false) is counted, logged, and tried again :data:`APPLY_RETRY_S` after its last
  try while the correction stays in force; a side has at most one call in flight (a driver
  that never answers gets one request every :data:`APPLY_RETRY_S`).

The services are beside each image's camera_info topic (``/cam/left/camera_info`` ->
``/cam/left/set_camera_info``) unless ``left/set_camera_info`` (``right/set_camera_info``) is
remapped.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from rclpy.lifecycle import LifecycleNode
from rclpy.publisher import Publisher
from sensor_msgs.msg import CameraInfo, CompressedImage, Image
from sensor_msgs.srv import SetCameraInfo
from std_msgs.msg import Header

from sepfm_ros.ros.node.camera_info import node_camera_info_topic
from sepfm_ros.ros.node.keep_serving import ThrottledLog
from sepfm_ros.ros.node.lifecycle import state_name
from sepfm_ros.ros.node.outputs import RELIABLE

if TYPE_CHECKING:  # the calibration modules load at configure, off the node's start-up path
    from sepfm_ros.geometry.calibrated.camera import CameraModel
    from sepfm_ros.pipeline.calibration import StreamCalibration

SIDES = ("left", "right")
SET_CAMERA_INFO = "set_camera_info"
APPLY_TIMEOUT_S = 10.0  # s a driver has to answer set_camera_info
APPLY_RETRY_S = 30.0  # s between tries of a side whose set_camera_info failed


def corrected_topic(side: str, kind: str) -> str:
    """``~/corrected/<side>/<kind>`` (kind ``image_raw`` or ``camera_info``)."""
    return f"~/corrected/{side}/{kind}"


def set_camera_info_service(node: Any, image_base: str) -> str:
    """The driver's ``set_camera_info`` service for the node's image input ``image_base``
    (``left/image_raw``): a remap of ``left/set_camera_info`` when given, else the service
    beside the camera_info topic the node follows
    (:func:`~sepfm_ros.ros.node.camera_info.node_camera_info_topic`)."""
    own = image_base.rsplit("/", 1)[0] + "/" + SET_CAMERA_INFO
    remapped = node.resolve_service_name(own)
    if remapped != node.resolve_service_name(own, only_expand=True):
        return str(remapped)
    info = node_camera_info_topic(node, image_base)
    return info.rsplit("/", 1)[0] + "/" + SET_CAMERA_INFO


def corrected_infos(models: tuple[CameraModel, CameraModel], headers: list[Header]) -> list[Any]:
    """The corrected CameraInfo of each camera under its image's header."""
    from sepfm_ros.ros.msgs.calibration import camera_info_from_model

    return [camera_info_from_model(m, h) for m, h in zip(models, headers, strict=True)]


def driver_models(
    corrected: tuple[CameraModel, CameraModel],
    received: tuple[CameraModel, CameraModel],
    rectified: bool,
) -> tuple[CameraModel, CameraModel]:
    """The calibration each driver should store for a correction.

    Raw input: the corrected models themselves. Rectified input (``image_rect``, whose
    camera_info is the driver's raw calibration, as image_proc publishes them): the corrected
    models describe the rectified images (K = the stale P's, R from the stale-rectified frame
    to the corrected one), so the driver's raw camera gets its own K and D with
    R = R_corrected R_received (raw frame -> stale-rectified -> corrected-rectified) and the
    corrected P.
    """
    from sepfm_ros.geometry.calibrated.camera import CameraModel

    if not rectified:
        return corrected
    a, b = (
        CameraModel(r.K, r.D, r.distortion_model, c.R @ r.R, c.P, r.width, r.height)
        for c, r in zip(corrected, received, strict=True)
    )
    return a, b


class CorrectedTopics:
    """The ``~/corrected/<side>/image_raw`` and ``.../camera_info`` lifecycle publishers of a
    stereo node (created at configure: ``publish_corrected`` is read-only; they publish while
    the node is active). With ``image_transport:=compressed`` the images go out as received on
    image_transport's compressed topic of that base, ``~/corrected/<side>/image_raw/compressed``
    (a consumer subscribes with the compressed transport)."""

    def __init__(self, node: LifecycleNode, transport: str = "raw") -> None:
        self._node = node
        make = node.create_lifecycle_publisher
        kind, image_type = "image_raw", Image
        if transport == "compressed":
            kind, image_type = "image_raw/compressed", CompressedImage
        self.images = [make(image_type, corrected_topic(s, kind), RELIABLE) for s in SIDES]
        self.infos = [make(CameraInfo, corrected_topic(s, "camera_info"), RELIABLE) for s in SIDES]
        self.pairs_published = 0

    def publishers(self) -> list[Publisher]:
        return [*self.images, *self.infos]

    def subscribers(self) -> int:
        """Subscribers matched by the corrected topics (summed): demand."""
        return sum(p.get_subscription_count() for p in self.publishers())

    def publish(self, msgs: list[Any], models: tuple[CameraModel, CameraModel]) -> None:
        """Publish the pair's images ``msgs`` (left, right) again, each with the corrected
        camera_info under the image's own header (camera_info first, as drivers do)."""
        infos = corrected_infos(models, [m.header for m in msgs])
        for k, (msg, info) in enumerate(zip(msgs, infos, strict=True)):
            self.infos[k].publish(info)
            # an image read in place (raw subscription) goes out as the bytes it came in
            self.images[k].publish(getattr(msg, "serialized", msg))
        self.pairs_published += 1

    def destroy(self) -> None:
        for pub in self.publishers():
            self._node.destroy_lifecycle_publisher(pub)  # type: ignore[arg-type]


@dataclass
class _SideState:
    """One driver's set_camera_info: the correction generation it holds, its call in flight."""

    service: str
    applied: int = 0  # generation whose set_camera_info succeeded (0: none)
    pending: Any = None  # the future of the call in flight
    sent_at: float = 0.0  # monotonic time of the last try
    failures: int = 0
    successes: int = 0
    last_result: str = "not sent"
    tried: int = 0  # generation of the last try


class CorrectionSender:
    """Sends each new correction to the drivers' ``set_camera_info`` services (see the module
    docstring); :meth:`offer` from any thread, the calls from the node's executor."""

    def __init__(self, node: LifecycleNode, image_bases: list[str], log: ThrottledLog) -> None:
        self._node = node
        self._log = log
        self._lock = threading.Lock()
        self._sides = [_SideState(set_camera_info_service(node, b)) for b in image_bases]
        self._clients = [node.create_client(SetCameraInfo, s.service) for s in self._sides]
        self._infos: list[Any] | None = None
        self._generation = 0
        self._guard = node.create_guard_condition(self._send)
        services = ", ".join(s.service for s in self._sides)
        node.get_logger().info(
            f"apply_correction on: a correction of the rig will be sent to {services}"
        )

    def offer(self, generation: int, infos: list[Any] | None) -> None:
        """The correction in force (``generation`` counts corrections that came into force;
        ``infos``: its CameraInfo per camera, None: none in force). Wakes the executor when a
        side needs a call."""
        now = time.monotonic()
        with self._lock:
            self._generation, self._infos = generation, infos
            due = infos is not None and any(self._due(s, now) for s in self._sides)
        if due:
            self._guard.trigger()

    def _due(self, side: _SideState, now: float) -> bool:
        """Whether ``side`` needs the executor now (lock held): a call whose answer is overdue
        (to be counted as failed), or a new try."""
        if side.applied == self._generation:
            return False
        if side.pending is not None:
            return now - side.sent_at >= APPLY_TIMEOUT_S
        return self._try_due(side, now)

    def _try_due(self, side: _SideState, now: float) -> bool:
        """Whether ``side`` is to be called now: a correction it was not sent yet, or
        :data:`APPLY_RETRY_S` since its last try (lock held, no call in flight)."""
        return side.tried != self._generation or now - side.sent_at >= APPLY_RETRY_S

    def _send(self) -> None:
        """Executor: call set_camera_info on each side that needs it (only while active)."""
        if state_name(self._node) != "active":
            return
        now = time.monotonic()
        with self._lock:
            infos, generation = self._infos, self._generation
            due = [k for k, s in enumerate(self._sides) if infos and self._due(s, now)]
        for k in due:
            self._call(k, generation, infos[k] if infos else None, now)

    def _call(self, k: int, generation: int, info: Any, now: float) -> None:
        """Give up a call that had no answer in time (a failure), then call ``k``'s service if
        a try is due: at most one call per side in flight, a new try only
        :data:`APPLY_RETRY_S` after the last (a driver that never answers is not sent a new
        request every :data:`APPLY_TIMEOUT_S`)."""
        side, client = self._sides[k], self._clients[k]
        with self._lock:
            if side.pending is not None:  # the last call had no answer in time
                client.remove_pending_request(side.pending)
                side.pending.cancel()
                side.pending = None
                self._fail(side, f"no answer within {APPLY_TIMEOUT_S:.0f} s")
            if not self._try_due(side, now):
                return
            side.sent_at, side.tried = now, generation
        if not client.service_is_ready():
            with self._lock:
                self._fail(side, "the service is not available")
            return
        future = client.call_async(SetCameraInfo.Request(camera_info=info))
        with self._lock:
            side.pending = future
        future.add_done_callback(lambda f: self._answered(side, generation, f))

    def _answered(self, side: _SideState, generation: int, future: Any) -> None:
        """Executor: a driver's answer."""
        if future.cancelled():
            return
        response = future.result()
        stored = response is not None and bool(response.success)
        with self._lock:
            side.pending = None
            if stored:
                side.applied, side.successes = generation, side.successes + 1
                side.last_result = "stored"
            else:
                message = "" if response is None else response.status_message
                self._fail(side, f"refused: {message or 'no reason given'}")
        if stored:
            self._node.get_logger().info(f"{side.service}: the driver stored the correction")

    def _fail(self, side: _SideState, reason: str) -> None:
        """Count and log a failed try (lock held)."""
        side.failures += 1
        side.last_result = f"failed: {reason}"
        self._log.log(
            f"set_camera_info {side.service}",
            f"set_camera_info {side.service} {reason}; tried again every {APPLY_RETRY_S:.0f} s "
            "while the correction is in force",
        )

    def diagnostic_values(self) -> dict[str, Any]:
        """Per service: successful and failed calls and the last result; in all, failures."""
        with self._lock:
            values: dict[str, Any] = {
                "set_camera_info_failures": sum(s.failures for s in self._sides)
            }
            for side in self._sides:
                values[f"set_camera_info {side.service}"] = (
                    f"{side.successes} stored, {side.failures} failed; last: {side.last_result}"
                )
        return values

    def destroy(self) -> None:
        for client in self._clients:
            self._node.destroy_client(client)
        self._node.destroy_guard_condition(self._guard)
        self._clients = []


class CorrectedStereo:
    """What a stereo node does with the correction in force: the corrected topics
    (``publish``) and the drivers' set_camera_info (``apply``); either may be off.

    :meth:`update` (the estimate thread, after each pair) takes the correction in force;
    :meth:`pair_formed` (the executor, as each pair forms) republishes the pair with it.
    """

    def __init__(
        self,
        node: LifecycleNode,
        image_bases: list[str],
        log: ThrottledLog,
        values: dict[str, Any],
        transport: str = "raw",
    ) -> None:
        """``image_bases``: the node's image inputs (two: stereo; one: motion, where there is
        no correction and both are off); ``values``: the node's parameter values
        (``publish_corrected``, ``apply_correction``); ``transport``: the input's."""
        stereo = len(image_bases) == 2
        publish = stereo and bool(values["publish_corrected"])
        apply = stereo and bool(values["apply_correction"])
        self._lock = threading.Lock()
        self._log = log
        self._models: tuple[CameraModel, CameraModel] | None = None
        self.generation = 0  #: corrections that came into force
        self.topics = CorrectedTopics(node, transport) if publish else None
        self.sender = CorrectionSender(node, image_bases, log) if apply else None

    def update(self, calibration: StreamCalibration, images: list[Any]) -> None:
        """The correction in force after a pair: ``calibration``'s
        :meth:`~StreamCalibration.corrected_models` (none when it cannot build them: logged);
        ``images``: the pair's (left, right), whose headers the driver's camera_info gets."""
        import numpy as np

        from sepfm_ros.geometry.calibrated.camera import CalibrationError

        try:
            models = calibration.corrected_models()
        except (CalibrationError, ValueError, np.linalg.LinAlgError) as err:
            models = None
            self._log.log("correction_unusable", f"no corrected camera_info: {err}")
        received = calibration._models  # the camera_info models as received
        with self._lock:
            if models is not None and self._models is None:
                self.generation += 1
            self._models = models
            if self.sender is not None:
                infos = None
                if models is not None and received is not None:
                    stored = driver_models(models, received, calibration.rectified)
                    infos = corrected_infos(stored, [m.header for m in images])
                self.sender.offer(self.generation, infos)

    def pair_formed(self, msgs: list[Any]) -> None:
        """Executor: republish the stereo pair ``msgs`` (left, right Image) on the corrected
        topics while a correction is in force."""
        with self._lock:
            models = self._models
        if models is not None and self.topics is not None:
            self.topics.publish(msgs, models)

    def demand(self) -> int:
        """Subscribers of the corrected topics."""
        return 0 if self.topics is None else self.topics.subscribers()

    def diagnostic_values(self) -> dict[str, Any]:
        """For the node's /diagnostics status: whether a correction is in force, the pairs
        republished, the set_camera_info results."""
        with self._lock:
            values: dict[str, Any] = {
                "correction_in_force": int(self._models is not None),
                "corrections": self.generation,
            }
            if self.topics is not None:
                values["corrected_pairs_published"] = self.topics.pairs_published
            if self.sender is not None:
                values.update(self.sender.diagnostic_values())
        return values

    def destroy(self) -> None:
        with self._lock:
            if self.topics is not None:
                self.topics.destroy()
            if self.sender is not None:
                self.sender.destroy()
            self.topics = self.sender = None
