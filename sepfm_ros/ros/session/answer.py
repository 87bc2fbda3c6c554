"""One answer path: a pair of images in, the pair's messages out.

The live node, ``process`` and ``calibration_check`` all answer a pair here, so they give the
same answer for the same pair; nothing else composes outputs. A pair's answer
(:class:`PairAnswer`) is:

- ``sepfm_msgs/TwoViewEstimate`` (``~/estimate``): F, status code and text, counts, line pair,
  timings and, with camera_info, the pose; for a pair that never reached the estimator a
  failure record (``STATUS_BAD_INPUT`` with the kind counted in ``/diagnostics``, e.g.
  ``decode`` kinds or ``size_change``, or ``STATUS_INTERNAL_ERROR``) with zero counts; matches
  the estimator refused are ``STATUS_BAD_INPUT`` of kind ``estimator_input``, with their counts;
- ``sepfm_msgs/MatchArray`` (``~/matches``): every match (none in a failure record);
- with camera_info, when the pose is usable: for a stereo rig the ``geometry_msgs/TransformStamped``
  (``~/relative_transform``) and ``geometry_msgs/PoseWithCovarianceStamped`` (``~/relative_pose``)
  of camera b in camera a's optical frame; for one moving camera the angular velocity
  (``geometry_msgs/TwistWithCovarianceStamped``, ``~/angular_velocity``) and the unit translation
  direction (``geometry_msgs/Vector3Stamped``, ``~/translation_direction``);
  and the calibration check's ``diagnostic_msgs/DiagnosticStatus`` of a calibrated stereo rig,
  or the ERROR status of unusable camera_info, which ``~/calibration_check`` carries in a
  ``diagnostic_msgs/DiagnosticArray`` stamped with the pair's header
  (:meth:`PairAnswer.calibration_check`).

Before pairing, :func:`precheck` skips an input message whose fields are unusable (the node in
its callback, ``process`` as it reads the bag). The steps of a pair, for callers that split
them over threads (the node matches one pair while it estimates the previous one):
:func:`decode_pair` (images or a :class:`BadInput`), the
pipeline's ``match``, then :func:`answer_matched`; :func:`failure_answer` answers a pair that
never reached the estimator. :class:`~sepfm_ros.ros.session.session.Session` composes them
for a stream.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    pass
import math
from collections import OrderedDict
from collections.abc import Hashable, Mapping
from dataclasses import dataclass

import numpy as np
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import (
    PoseWithCovarianceStamped,
    Quaternion,
    Transform,
    TransformStamped,
    TwistWithCovarianceStamped,
    Vector3Stamped,
)
from std_msgs.msg import Header

from sepfm_msgs.msg import Match, MatchArray, StageTiming, TwoViewEstimate
from sepfm_ros.geometry.estimate import StatusCode
from sepfm_ros.pipeline.calibration import CalibratedOutputs
from sepfm_ros.pipeline.pipeline import MatchedPair, Pipeline, PipelineConfig, PipelineResult
from sepfm_ros.ros.msgs.calibration import calibration_check_message, relative_transform
from sepfm_ros.ros.msgs.fundamental import fundamental_field
from sepfm_ros.ros.msgs.headers import copy_header
from sepfm_ros.ros.msgs.image_conversion import (
    ImageDecodeError,
    check_compressed,
    check_image,
    pair_decoded,
)
from sepfm_ros.ros.session.calibrated import CalibratedStream, CamerasUpdate

SIZE_CHANGE = "size_change"  # bad-input kind: one camera's frame size changed within a pair
# bad-input kind: the estimator refused the matches (e.g. a non-finite point after undistortion)
ESTIMATOR_INPUT = "estimator_input"


@dataclass(frozen=True)
class BadInput:
    """Why a pair could not be estimated: the kind counted in ``/diagnostics`` and the text.

    ``sizes``: the images' (width, height) when they were decoded (a frame-size change).
    """

    kind: str
    text: str
    sizes: tuple[tuple[int, int], tuple[int, int]] | None = None


@dataclass(frozen=True)
class PairHeaders:
    """The headers of a pair: ``header`` stamps every output (the left image's in stereo, the
    newer frame's in motion); ``a`` and ``b`` are image a's and image b's own."""

    header: Header
    a: Header
    b: Header


@dataclass(frozen=True)
class DecodedPair:
    """A pair's images as the pipeline takes them: (H, W) uint8 each, and the decode time."""

    images: tuple[np.ndarray, np.ndarray]
    decode_ms: float


@dataclass(frozen=True)
class AnswerSettings:
    """What the answer needs beyond the pipeline's config (the node's parameters).

    ``publish_unreliable``: an F whose status is not ok is still given (``has_f``);
    ``threshold_px``: the estimator's inlier threshold (scale of the pose refinement).
    """

    features: str
    method: str
    publish_unreliable: bool
    threshold_px: float

    @classmethod
    def of(cls, config: PipelineConfig, publish_unreliable: bool) -> AnswerSettings:
        """The settings of a pipeline config (and the node's ``publish_unreliable``)."""
        return cls(
            config.features, config.method, bool(publish_unreliable), float(config.threshold_px)
        )


@dataclass(frozen=True)
class PairCalibration:
    """A stream's calibration and the latest camera_info of each of its cameras (None: none
    received yet)."""

    stream: CalibratedStream
    infos: list[Any] | None


@dataclass
class PairAnswer:
    """One pair's messages, and what they were made from (for logs, health and drawing).

    Attributes:
        estimate: the TwoViewEstimate (always).
        matches: the MatchArray (always; empty for a failure record).
        transform: the relative pose of a stereo rig, when calibrated and usable.
        relative_pose: the same with its covariance (when the inliers give one).
        angular_velocity, translation_direction: a moving camera's rotation rate with its
            covariance, and its unit translation direction.
        calibration: the calibration check, or the ERROR status of unusable camera_info.
        result: the pipeline's result (None for a failure record).
        cameras_update: what the camera_info gave this pair (None without calibration input).
        calibrated: the pose and check behind ``transform`` and ``calibration``.
        error: the exception behind a ``STATUS_INTERNAL_ERROR`` record (for the log).
    """

    estimate: TwoViewEstimate
    matches: MatchArray
    transform: TransformStamped | None = None
    calibration: DiagnosticStatus | None = None
    relative_pose: PoseWithCovarianceStamped | None = None
    angular_velocity: TwistWithCovarianceStamped | None = None
    translation_direction: Vector3Stamped | None = None
    result: PipelineResult | None = None
    cameras_update: CamerasUpdate | None = None
    calibrated: CalibratedOutputs | None = None
    error: BaseException | None = None

    @property
    def has_f(self) -> bool:
        return bool(self.estimate.has_f)

    def calibration_check(self) -> DiagnosticArray | None:
        """The ``~/calibration_check`` message: ``calibration`` stamped with the pair's header
        (the estimate's); None without a calibration status."""
        if self.calibration is None:
            return None
        return calibration_check_message(self.estimate.header, self.calibration)


def precheck(msg: Any) -> BadInput | None:
    """The node's cheap check of one input message's fields (no pixel access), before it is
    paired: a message that fails it is skipped (counted by kind), never paired or answered.
    ``msg``: a sensor_msgs/Image or CompressedImage (rclpy or rosbags message)."""
    try:
        if hasattr(msg, "encoding"):
            check_image(msg)
        else:
            check_compressed(msg)
    except ImageDecodeError as err:
        return BadInput(err.kind, str(err))
    return None


class DecodedFrames:
    """The mono8 images of the latest frames by key, so that a frame that is image b of one pair
    and image a of the next (motion mode) is converted once.

    Only images of 8-bit pixels are kept: their mono8 image does not depend on the pair's other
    image (deeper pixels are mapped with the pair's range, see ``pair_to_numpy``), so a kept
    image equals what decoding the message again gives. Not thread-safe: one decoding thread.
    """

    def __init__(self, size: int = 2) -> None:
        self._images: OrderedDict[Hashable, np.ndarray] = OrderedDict()
        self._size = int(size)
        self.reused = 0  # images taken from here instead of decoded again

    def get(self, key: Hashable | None) -> np.ndarray | None:
        """The kept (H, W) uint8 image of frame ``key`` (None: not kept, or no key)."""
        if key is None or key not in self._images:
            return None
        self.reused += 1
        return self._images[key]

    def put(self, key: Hashable | None, image: np.ndarray) -> None:
        """Keep frame ``key``'s mono8 image (the oldest kept one goes beyond ``size``)."""
        if key is None or self._size <= 0:
            return
        self._images[key] = image
        self._images.move_to_end(key)
        while len(self._images) > self._size:
            self._images.popitem(last=False)


def decode_pair(
    msg_a: Any,
    msg_b: Any,
    stereo: bool,
    frames: DecodedFrames | None = None,
    keys: tuple[Hashable | None, Hashable | None] = (None, None),
) -> DecodedPair | BadInput:
    """Decode a pair's Image/CompressedImage messages to mono8 with one contrast for the pair.

    A stereo rig's two cameras may differ in size (F relates any two views); one camera whose
    frame size changed between the two frames gives a :class:`BadInput` of kind ``size_change``.
    With ``frames`` and the frames' ``keys``, image a is taken from ``frames`` when an earlier
    pair decoded it (motion mode: the previous pair's image b), and image b is kept there.
    """
    t0 = time.perf_counter()
    known_a = frames.get(keys[0]) if frames is not None else None
    try:
        image_a, image_b, reusable = pair_decoded(msg_a, msg_b, "mono8", known_a)
    except ImageDecodeError as err:
        return BadInput(err.kind, str(err))
    if frames is not None and reusable:
        frames.put(keys[1], image_b)
    decode_ms = (time.perf_counter() - t0) * 1e3
    size_a, size_b = _size(image_a), _size(image_b)
    if not stereo and size_a != size_b:
        return BadInput(
            SIZE_CHANGE,
            f"the camera's frame size changed from {size_a} to {size_b}",
            (size_a, size_b),
        )
    return DecodedPair((image_a, image_b), decode_ms)


def _size(image: np.ndarray) -> tuple[int, int]:
    return int(image.shape[1]), int(image.shape[0])


def answer_matched(
    pipeline: Pipeline,
    headers: PairHeaders,
    matched: MatchedPair,
    settings: AnswerSettings,
    calibration: PairCalibration | None = None,
    timings_ms: Mapping[str, float] | None = None,
) -> PairAnswer:
    """Estimate a matched pair (undistorted with the camera_info's cameras, when usable) and
    compose its messages. ``timings_ms``: extra stages for the estimate (the node's wait,
    queue)."""
    update, cameras = None, None
    if calibration is not None:
        update = calibration.stream.cameras(calibration.infos, [matched.size_a, matched.size_b])
        cameras = update.cameras
    result = pipeline.estimate(matched, cameras)
    answer = PairAnswer(TwoViewEstimate(), MatchArray(), result=result, cameras_update=update)
    if update is not None and update.error is not None:
        answer.calibration = update.error
    if cameras is not None and calibration is not None:
        t0 = time.perf_counter()
        stream = calibration.stream
        frames = stream.frames(headers.a.frame_id, headers.b.frame_id)
        dt_s = _seconds(headers.b) - _seconds(headers.a)
        messages = stream.messages(result, settings.threshold_px, headers.header, frames, dt_s)
        answer.transform = messages.transform
        answer.relative_pose = messages.relative_pose
        answer.angular_velocity = messages.angular_velocity
        answer.translation_direction = messages.translation_direction
        answer.calibrated = messages.outputs
        if messages.status is not None:
            answer.calibration = messages.status
        result.timings_ms["pose"] = (time.perf_counter() - t0) * 1e3
    coordinates = result.coordinates
    if cameras is not None and calibration is not None:
        if calibration.stream.calibration.rectified and coordinates == "undistorted":
            coordinates = "rectified"
    has_infos = calibration is not None and calibration.infos is not None
    answer.estimate = estimate_message(
        headers, result, settings, coordinates, answer.calibrated, has_infos
    )
    add_timings(answer.estimate, timings_ms or {})
    answer.matches = match_array(headers, result)
    return answer


def failure_answer(headers: PairHeaders, bad: BadInput, settings: AnswerSettings) -> PairAnswer:
    """The failure record of a pair whose images could not be used (``STATUS_BAD_INPUT``)."""
    msg = _base_message(headers, settings)
    msg.status = int(StatusCode.BAD_INPUT)
    msg.status_text = f"bad input ({bad.kind}): {bad.text}"
    msg.bad_input_kind = bad.kind
    if bad.sizes is not None:
        (msg.width_a, msg.height_a), (msg.width_b, msg.height_b) = bad.sizes
    return PairAnswer(msg, _empty_matches(headers))


def internal_error_answer(
    headers: PairHeaders, err: BaseException, settings: AnswerSettings
) -> PairAnswer:
    """The failure record of a pair whose answer raised (``STATUS_INTERNAL_ERROR``)."""
    msg = _base_message(headers, settings)
    msg.status = int(StatusCode.INTERNAL_ERROR)
    msg.status_text = f"internal error: {type(err).__name__}: {err}"
    return PairAnswer(msg, _empty_matches(headers), error=err)


def add_timings(msg: TwoViewEstimate, timings_ms: Mapping[str, float]) -> None:
    """Append stages (name -> ms) to an estimate's timings (e.g. the node's publish time)."""
    msg.timings.extend(StageTiming(stage=str(k), ms=float(v)) for k, v in timings_ms.items())


def _stamp(header: Header) -> Time:
    return Time(sec=int(header.stamp.sec), nanosec=int(header.stamp.nanosec))


def _seconds(header: Header) -> float:
    return int(header.stamp.sec) + int(header.stamp.nanosec) * 1e-9


def _identity() -> Transform:
    return Transform(rotation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0))


def _base_message(headers: PairHeaders, settings: AnswerSettings) -> TwoViewEstimate:
    """The fields every answer has: headers, stamps, frames, method, features; no F, no
    counts, NaN figures, no pose."""
    return TwoViewEstimate(
        header=copy_header(headers.header),
        stamp_a=_stamp(headers.a),
        frame_id_a=str(headers.a.frame_id),
        stamp_b=_stamp(headers.b),
        frame_id_b=str(headers.b.frame_id),
        method=settings.method,
        features=settings.features,
        inlier_error_px=math.nan,
        log10_nfa=math.nan,
        pose_kind=TwoViewEstimate.POSE_NONE,
        pose=_identity(),
        rotation_deg=math.nan,
    )


def _empty_matches(headers: PairHeaders) -> MatchArray:
    return MatchArray(
        header=copy_header(headers.header), stamp_a=_stamp(headers.a), stamp_b=_stamp(headers.b)
    )


def estimate_message(
    headers: PairHeaders,
    result: PipelineResult,
    settings: AnswerSettings,
    coordinates: str,
    calibrated: CalibratedOutputs | None,
    calibration_input: bool,
) -> TwoViewEstimate:
    """A pipeline result -> TwoViewEstimate. F is given (``has_f``) when it exists and is ok,
    or unreliable with ``settings.publish_unreliable``. ``calibration_input``: the pair had
    camera_info messages (the pose fields say what became of them; empty without)."""
    est = result.estimate
    msg = _base_message(headers, settings)
    (msg.width_a, msg.height_a), (msg.width_b, msg.height_b) = result.size_a, result.size_b
    msg.method = est.method or settings.method
    msg.features = settings.features
    msg.has_f = est.F is not None and (result.ok or settings.publish_unreliable)
    if msg.has_f:
        msg.f = fundamental_field(est.F)
    msg.status = int(est.code)
    msg.status_text = "ok" if result.ok else est.status
    if est.code == StatusCode.BAD_INPUT:
        msg.bad_input_kind = ESTIMATOR_INPUT
    msg.coordinates = coordinates
    msg.matches = len(result.matches)
    msg.inliers = est.num_inliers
    if est.F is not None and est.num_inliers:
        msg.inlier_error_px = float(np.median(result.errors[est.inliers]))
    msg.hypotheses = int(est.hypotheses)
    msg.stage1_hypotheses = int(est.stage1_hypotheses)
    msg.stage2_hypotheses = int(est.stage2_hypotheses)
    msg.samples = int(est.samples)
    msg.fallback = bool(est.fallback)
    msg.unfixed_lead = bool(est.unfixed_lead)
    msg.line_search_skipped = bool(est.line_search_skipped)
    if est.log10_nfa is not None:
        msg.log10_nfa = float(est.log10_nfa)
    if est.line_pair is not None:
        msg.has_line_pair = True
        msg.line_a = [float(c) for c in est.line_pair[0]]
        msg.line_b = [float(c) for c in est.line_pair[1]]
    msg.line_inliers = len(est.line_inliers)
    add_timings(msg, result.timings_ms)
    if calibration_input:
        _set_pose(msg, result, calibrated)
    return msg


def _set_pose(
    msg: TwoViewEstimate, result: PipelineResult, calibrated: CalibratedOutputs | None
) -> None:
    """The pose fields of a pair that had camera_info messages."""
    pose = None if calibrated is None else calibrated.pose
    if result.coordinates != "undistorted":
        msg.pose_status = "camera_info unusable (see ~/calibration_check)"
        return
    if pose is None:
        msg.pose_status = f"no F: {result.estimate.status}"
        return
    msg.pose_status = pose.status
    if not pose.ok:
        return
    msg.pose = relative_transform(pose, Header(), "", "").transform
    msg.pose_kind = TwoViewEstimate.POSE_METRIC if calibrated.scaled else TwoViewEstimate.POSE_UNIT
    msg.rotation_deg = float(pose.rotation_deg)
    msg.inliers_in_front = int(round(pose.in_front * pose.n_points))


def match_array(headers: PairHeaders, result: PipelineResult) -> MatchArray:
    """Every match of a result (in the estimate's coordinates) as a MatchArray."""
    m = result.matches
    rows = zip(
        m.pts_a[:, 0].tolist(),
        m.pts_a[:, 1].tolist(),
        m.pts_b[:, 0].tolist(),
        m.pts_b[:, 1].tolist(),
        np.asarray(result.errors, dtype=np.float64).tolist(),
        np.asarray(result.estimate.inliers, dtype=bool).tolist(),
        np.asarray(result.on_line, dtype=bool).tolist(),
        strict=True,
    )
    out = _empty_matches(headers)
    out.matches = [
        Match(u_a=ua, v_a=va, u_b=ub, v_b=vb, error_px=e, inlier=i, on_line=o)
        for ua, va, ub, vb, e, i, o in rows
    ]
    return out
