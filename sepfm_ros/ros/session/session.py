"""One stream's set-up and the answer to each of its pairs, whoever asks.

A :class:`Session` is built from the node's parameter values (:mod:`.parameters`: the same names,
defaults and ranges whether they come from a live node, ``-p NAME:=VALUE`` or a params file) and
the stream's input topics. It owns everything a stream needs: the
:class:`~sepfm_ros.pipeline.pipeline.Pipeline`, the answer settings, the raw/rectified decision
(:func:`images_rectified`, one rule everywhere), the calibration from camera_info with its
monitor (:class:`~.calibrated.CalibratedStream`) and the pairing of frames
(:meth:`Session.pairing`). The live node, ``process``, ``calibration_check`` and ``audit`` all
build one and answer every pair through it (:mod:`.answer`), so they give the same answer for
the same pair.

Thread safety: :meth:`Session.configure` may be called from any thread (the node's parameter
callback); the new pipeline config takes effect at the next :meth:`Session.match`, the new
monitor at the next :meth:`Session.answer_matched`. One thread matches and one estimates.
"""

from __future__ import annotations

import threading
from collections.abc import Hashable, Mapping, Sequence
from typing import Any

from sepfm_ros.geometry.calibrated.calibration_check import MonitorConfig
from sepfm_ros.geometry.calibrated.correction import CorrectionConfig
from sepfm_ros.pipeline.pipeline import MatchedPair, Pipeline, PipelineConfig
from sepfm_ros.ros.session.answer import (
    AnswerSettings,
    BadInput,
    DecodedFrames,
    DecodedPair,
    PairAnswer,
    PairCalibration,
    PairHeaders,
    answer_matched,
    decode_pair,
    failure_answer,
    internal_error_answer,
)
from sepfm_ros.ros.session.calibrated import CalibratedStream
from sepfm_ros.ros.session.parameters import (
    NODE_NAME,
    ParameterError,
    correction_config,
    monitor_config,
    parameter_error,
    pipeline_config,
)
from sepfm_ros.stream.pairing import MotionPairing, StereoPairing

RECTIFIED_HINT = "rect"  # a topic named like image_rect carries rectified images


def images_rectified(images: str, topics: Sequence[str]) -> bool:
    """What the ``images`` parameter says of the input images: ``rectified``, ``raw``, or for
    ``auto`` rectified when every input topic's name contains ``rect`` (``image_rect``,
    ``image_rect_color``). ``topics``: the input image topics as resolved (remaps applied)."""
    if images != "auto":
        return images == "rectified"
    return bool(topics) and all(RECTIFIED_HINT in t for t in topics)


def pairing_settings(values: Mapping[str, Any], slop_ns: int | None = None) -> dict[str, Any]:
    """The pairing's settings from parameter values: the stereo slop (ns; ``slop_ns`` overrides
    ``sync_slop_s``), the stereo queue, the motion frame gap and the stamp-jump reset (s)."""
    return {
        "slop_ns": int(round(values["sync_slop_s"] * 1e9)) if slop_ns is None else int(slop_ns),
        "queue": int(values["sync_queue_size"]),
        "frame_gap": int(values["frame_gap"]),
        "jump_s": float(values["stamp_jump_reset_s"]),
    }


class Session:
    """A stream's set-up and its answers (see the module docstring).

    Args:
        values: every node parameter's value (:data:`~.parameters.PARAMS` names).
        stereo: two cameras of a rig (else one camera's frames over time).
        topics: the input image topics (resolved), for the ``images: auto`` rule.
        status_name: the node's fully qualified name, in the calibration status's name (offline:
            ``/sepfm``, the node the outputs are named for); hardware_id: its id.
        cache_size: frames whose features are kept (motion: each frame is detected once).
        parallel_detect: detect the second image on a helper thread (the live node).

    Raises:
        ParameterError: a value out of range or of the wrong type.
    """

    def __init__(
        self,
        values: Mapping[str, Any],
        stereo: bool,
        topics: Sequence[str],
        status_name: str = "/" + NODE_NAME,
        hardware_id: str = "",
        cache_size: int = 8,
        parallel_detect: bool = False,
    ) -> None:
        errors = [e for n, v in values.items() if (e := parameter_error(n, v))]
        if errors:
            raise ParameterError("invalid parameters: " + "; ".join(errors))
        self.values = dict(values)
        self.stereo = stereo
        self.rectified = images_rectified(str(values["images"]), topics)
        try:
            config, monitor = pipeline_config(self.values), monitor_config(self.values)
            correction = correction_config(self.values)
        except ValueError as err:
            raise ParameterError(str(err)) from None
        # a calibrated stereo rig's correction fits sub-pixel points of image b
        self.pipeline = Pipeline(
            config,
            cache_size=cache_size,
            parallel_detect=parallel_detect,
            subpixel_b=stereo and bool(values["use_camera_info"]),
        )
        # motion: each frame converted to mono8 once (image b of a pair, image a of the next)
        self.frames = DecodedFrames(int(values["frame_gap"]) + 1)
        self.calibrated = CalibratedStream(
            stereo, self.rectified, monitor, status_name, hardware_id, correction
        )
        self.uses_camera_info = bool(values["use_camera_info"])
        self._lock = threading.Lock()
        self._publish_unreliable = bool(values["publish_unreliable"])
        self._pending_config: PipelineConfig | None = None
        self._pending_monitor: tuple[MonitorConfig, CorrectionConfig] | None = None

    # ---------------------------------------------------------------- set-up
    def pairing(self, slop_ns: int | None = None) -> StereoPairing[Any] | MotionPairing[Any]:
        """A new pairing of this stream's frames (stereo by stamp, motion by frame gap).
        ``slop_ns``: the stereo slop, when not ``sync_slop_s`` (offline: half the frame period)."""
        s = pairing_settings(self.values, slop_ns)
        if self.stereo:
            return StereoPairing(s["slop_ns"], s["queue"], s["jump_s"])
        return MotionPairing(s["frame_gap"], s["jump_s"])

    def configure(self, values: Mapping[str, Any]) -> None:
        """New run-time parameter values (validated by the caller,
        :func:`~.parameters.change_errors`); see the module docstring for when they apply."""
        config, monitor = pipeline_config(dict(values)), monitor_config(dict(values))
        correction = correction_config(dict(values))
        with self._lock:
            self.values = dict(values)
            self._pending_config, self._pending_monitor = config, (monitor, correction)
            self._publish_unreliable = bool(values["publish_unreliable"])

    def settings(self, config: PipelineConfig | None = None) -> AnswerSettings:
        """The answer's settings for a pair matched with ``config`` (default: the current)."""
        with self._lock:
            publish_unreliable = self._publish_unreliable
        return AnswerSettings.of(config or self.pipeline.config, publish_unreliable)

    # ---------------------------------------------------------------- a pair
    def decode(
        self, msg_a: Any, msg_b: Any, keys: tuple[Hashable, Hashable] = (None, None)
    ) -> DecodedPair | BadInput:
        """A pair's mono8 images (:func:`~.answer.decode_pair`); a frame already decoded as
        the previous pair's image b (same key) is not decoded again. One decoding thread."""
        return decode_pair(msg_a, msg_b, self.stereo, self.frames, keys)

    def match(
        self, decoded: DecodedPair, key_a: Hashable = None, key_b: Hashable = None
    ) -> MatchedPair:
        """Features and matches of a decoded pair (a pending config is applied first).
        ``key_a``/``key_b``: the feature cache's keys of the two frames."""
        with self._lock:
            config, self._pending_config = self._pending_config, None
        if config is not None:
            self.pipeline.configure(config)
        return self.pipeline.match(
            *decoded.images, key_a, key_b, prior_timings_ms={"decode": decoded.decode_ms}
        )

    def answer_matched(
        self,
        headers: PairHeaders,
        matched: MatchedPair,
        infos: list[Any] | None,
        timings_ms: Mapping[str, float] | None = None,
    ) -> PairAnswer:
        """Estimate a matched pair and compose its messages (a pending monitor config is applied
        first). ``infos``: the camera_info of each camera for this pair (None: none yet);
        ignored unless ``use_camera_info``."""
        with self._lock:
            monitor, self._pending_monitor = self._pending_monitor, None
        if monitor is not None:
            self.calibrated.configure_monitor(*monitor)
        calibration = PairCalibration(self.calibrated, infos) if self.uses_camera_info else None
        settings = self.settings(matched.config)
        return answer_matched(self.pipeline, headers, matched, settings, calibration, timings_ms)

    def answer(
        self,
        headers: PairHeaders,
        msg_a: Any,
        msg_b: Any,
        keys: tuple[Hashable, Hashable] = (None, None),
        infos: list[Any] | None = None,
    ) -> PairAnswer:
        """The whole path for one pair of image messages: decode, match, estimate, compose.
        Never raises on a pair: undecodable images give the failure record, an unexpected error
        the ``STATUS_INTERNAL_ERROR`` record."""
        return self.answer_decoded(headers, self.decode(msg_a, msg_b, keys), keys, infos)

    def answer_decoded(
        self,
        headers: PairHeaders,
        decoded: DecodedPair | BadInput,
        keys: tuple[Hashable, Hashable] = (None, None),
        infos: list[Any] | None = None,
    ) -> PairAnswer:
        """:meth:`answer` from the decoded images (or why they could not be decoded)."""
        if isinstance(decoded, BadInput):
            return self.failure(headers, decoded)
        try:
            matched = self.match(decoded, *keys)
            return self.answer_matched(headers, matched, infos)
        except Exception as err:  # noqa: BLE001 - every pair gets an answer
            return self.internal_error(headers, err)

    def failure(self, headers: PairHeaders, bad: BadInput) -> PairAnswer:
        """The failure record of a pair whose images could not be used."""
        return failure_answer(headers, bad, self.settings())

    def internal_error(self, headers: PairHeaders, err: BaseException) -> PairAnswer:
        """The ``STATUS_INTERNAL_ERROR`` record of a pair whose processing raised ``err``."""
        return internal_error_answer(headers, err, self.settings())


def configure_pairing(
    pairing: StereoPairing[Any] | MotionPairing[Any], values: Mapping[str, Any]
) -> None:
    """Apply run-time parameter ``values`` to a running pairing (keeps its queued frames)."""
    s = pairing_settings(values)
    if isinstance(pairing, StereoPairing):
        pairing.configure(s["slop_ns"], s["queue"], s["jump_s"])
    else:
        pairing.configure(s["frame_gap"], s["jump_s"])
