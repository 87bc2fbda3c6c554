"""The live two-view geometry node ``sepfm``: images in, typed estimates and matches out.

Run it as ``sepfm_ros node --ros-args ...`` (or ``ros2 run sepfm_ros node --ros-args ...``).

This module wires the parts together; each lives in its own module: the parameters
(:mod:`sepfm_ros.ros.session.parameters`), the image topics and their QoS
(:mod:`~sepfm_ros.ros.node.subscriptions`), the lifecycle, warm-up and demand
(:mod:`~sepfm_ros.ros.node.lifecycle`), stereo and motion pairing
(:mod:`sepfm_ros.stream.pairing`), the latest-only slots between the executor and the two worker
threads (:mod:`~sepfm_ros.stream.scheduling`), health (:mod:`~sepfm_ros.stream.health`), and a
knocked rig's corrected topics and set_camera_info calls (:mod:`~sepfm_ros.ros.node.corrected`).

Threading: the executor (single-threaded) only runs cheap callbacks: they validate a message's
fields, pair frames and offer the pair to the scheduler. Two worker threads then run the
:class:`~sepfm_ros.pipeline.pipeline.Pipeline` one pair apart: ``sepfm-match`` decodes the images,
detects features (each frame once, cached by stamp; in stereo mode the right image on a helper
thread) and matches them; ``sepfm-estimate`` runs the estimator (``max_samples`` caps its RANSAC
samples) and publishes. Each pair goes through exactly the calls of :meth:`Pipeline.process`, so
results equal offline processing. docs/design.md gives the reasons and measurements.
"""

from __future__ import annotations

import threading
import time
from collections import Counter
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, cast

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rcl_interfaces.msg import SetParametersResult
from rclpy.parameter import Parameter
from sensor_msgs.msg import CompressedImage, Image
from std_msgs.msg import Header

from sepfm_ros.ros.msgs.diagnostics import diagnostic_array, health_status, status_name
from sepfm_ros.ros.msgs.headers import copy_header, stamp_ns
from sepfm_ros.ros.msgs.image_conversion import ZeroStepNotes
from sepfm_ros.ros.node.camera_info import CameraInfoInputs, calibration_in_use_text
from sepfm_ros.ros.node.corrected import CorrectedStereo
from sepfm_ros.ros.node.dds import UNCONFIGURED, DdsSetup
from sepfm_ros.ros.node.jobs import Job, MatchedJob, start_worker
from sepfm_ros.ros.node.keep_serving import ThrottledLog, guarded
from sepfm_ros.ros.node.lifecycle import (
    IDLE,
    WARMING_UP,
    DemandGate,
    KernelWarmUp,
    ManagedNode,
    start_when_ready,
    state_name,
)
from sepfm_ros.ros.node.memory import release_free_memory
from sepfm_ros.ros.node.outputs import RELIABLE, NodeOutputs
from sepfm_ros.ros.node.subscriptions import InputSubscription, input_topic, subscription_values
from sepfm_ros.ros.session.internal_errors import internal_error_kind, internal_error_text
from sepfm_ros.ros.session.parameters import (
    DIAGNOSTIC_PERIOD,
    NODE_NAME,
    PARAMS,
    always_on_default,
    change_errors,
    descriptor,
    parameter_error,
    renamed_values,
)
from sepfm_ros.stream.health import ERROR, OK, STALL_CHECK_PERIOD_S, WARN, Health
from sepfm_ros.stream.pairing import Frame, MotionPairing, PairOutcome, StereoPairing
from sepfm_ros.stream.scheduling import PairScheduler
from sepfm_ros.stream.sync import LEFT, RIGHT

if TYPE_CHECKING:  # imported where first used, after the warm-up: off the start-up path
    from sepfm_ros.ros.session.answer import BadInput, PairAnswer
    from sepfm_ros.ros.session.calibrated import CamerasUpdate
    from sepfm_ros.ros.session.session import Session

LEVEL_BYTES = {OK: DiagnosticStatus.OK, WARN: DiagnosticStatus.WARN, ERROR: DiagnosticStatus.ERROR}


class SepfmNode(ManagedNode):
    """The ``sepfm`` node (see the module docstring), a lifecycle node
    (:class:`~sepfm_ros.ros.node.lifecycle.ManagedNode`)."""

    _session: Session
    _pairing: StereoPairing[Any] | MotionPairing[Any]
    _out: NodeOutputs
    _scheduler: PairScheduler[Job, MatchedJob]
    _workers: list[threading.Thread]

    def __init__(
        self,
        node_name: str = NODE_NAME,
        dds: DdsSetup | None = None,
        warm: KernelWarmUp | None = None,
        **kwargs: Any,
    ) -> None:
        """``dds``: the process's Fast DDS setup (:func:`sepfm_ros.ros.node.dds.configure_dds`), for
        the log, ``/diagnostics`` and the advice on lost samples (None: not configured).
        ``warm``: the kernel warm-up the process started (None: configure warms up)."""
        super().__init__(node_name, warm or KernelWarmUp(), **kwargs)
        self._dds = dds or DdsSetup(False, UNCONFIGURED)
        values = self._declare_parameters()
        self._mode = values["mode"]
        self._transport = values["image_transport"]
        self._always_on = bool(values["always_on"])
        self._zero_step = ZeroStepNotes()  # step-0 images read as packed: warned once per topic

        self._lock = threading.Lock()  # guards the settings below and the pairing
        self._epipolar_lines = int(values["debug_epipolar_lines"])
        names = ("left", "right") if self._mode == "stereo" else ("image",)
        self._health = Health(names, float(values["input_timeout_s"]))
        self._log = ThrottledLog(self)
        self._reported_stall: str | None = None
        self._diagnostics = self.create_publisher(DiagnosticArray, "/diagnostics", RELIABLE)

        self._qos_switches: Counter[str] = Counter()  # input_reliability auto, by new reliability
        self._inputs = self._input_callbacks()
        self._bases = [base for base, _ in self._inputs]
        self._subs: list[InputSubscription] = []
        self._camera_info: CameraInfoInputs | None = None
        self._calib_status: DiagnosticStatus | None = None  # latest, also in /diagnostics
        self._demand = DemandGate(self, self._wanted, self._subscribe, self._unsubscribe)
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        self._diag_timer = self.create_timer(values[DIAGNOSTIC_PERIOD], self._report_health)
        self._stall_timer = self.create_timer(STALL_CHECK_PERIOD_S, self._check_level_change)
        self._stall_timer.cancel()  # runs while the inputs are held (no wake-ups while idle)
        if values["autostart"]:
            start_when_ready(self)

    def configure_node(self, warm_s: float) -> None:
        """The pipeline, the outputs and the workers (the kernels are ready)."""
        from sepfm_ros.ros.session.session import Session

        values = self._param_values()
        self._session = Session(
            values,
            self._mode == "stereo",
            [self.resolve_topic_name(b) for b in self._bases],
            self.get_fully_qualified_name(),
            self.get_fully_qualified_name(),
            cache_size=8,
            parallel_detect=True,
        )
        self._pairing = self._session.pairing()
        self._scheduler = PairScheduler()
        self._out = NodeOutputs(self, self._diagnostics)
        self._corrected = CorrectedStereo(self, self._bases, self._log, values, self._transport)
        self._calib_status = None
        self._workers = [
            start_worker(self._match_loop, "sepfm-match"),
            start_worker(self._estimate_loop, "sepfm-estimate"),
        ]
        self.get_logger().info(
            f"configured (estimator kernels ready in {warm_s:.1f} s): {self._mode} mode, "
            f"{self._transport} transport, input reliability {values['input_reliability']}, "
            f"{'always on' if self._always_on else 'on demand'}; {self._session.pipeline.config}"
        )

    def activate_inputs(self) -> None:
        """Hold the inputs while there is demand."""
        self._demand.enable()
        if not self._demand.on:
            self.get_logger().info("active, idle: no subscribers to the outputs yet")

    def deactivate_inputs(self) -> None:
        self._demand.disable()

    def release_node(self) -> None:
        """Stop the workers and destroy the outputs."""
        self.shutdown()
        self._out.destroy()
        self._corrected.destroy()

    def _wanted(self) -> bool:
        """Whether the node should hold its inputs: ``always_on``, or an answer subscriber
        (the corrected topics' among them)."""
        return self._always_on or self._out.demand() + self._corrected.demand() > 0

    def _subscribe(self) -> None:
        """Demand came: subscribe to the inputs with fresh pairing (no pair of older frames)."""
        with self._lock:
            self._pairing = self._session.pairing()
        self._scheduler.reset_input()
        self._health.restart_input()
        self._stall_timer.reset()
        values = self._param_values()
        self._subs = self._input_subscriptions(self._inputs, values["input_reliability"])
        if self._camera_info is None:
            self._camera_info = self._camera_info_inputs(values, self._bases)
        else:
            self._camera_info.resume()
        why = "always_on" if self._always_on else "the outputs have subscribers"
        self.get_logger().info(f"answering ({why}): on {', '.join(s.topic for s in self._subs)}")

    def _unsubscribe(self) -> None:
        """Demand left (or deactivate): release the inputs."""
        for sub in self._subs:
            sub.destroy()
        self._subs = []
        self._stall_timer.cancel()
        if self._camera_info is not None:
            self._camera_info.pause()
        self.get_logger().info("idle: no subscribers to the outputs; input subscriptions released")

    def _declare_parameters(self) -> dict[str, Any]:
        """Declare every parameter; their values (ValueError listing the invalid ones)."""
        # values given under an old name: warned, and used unless the new name is given too
        aliased, texts = renamed_values(getattr(self, "_parameter_overrides", {}))
        for text in texts:
            self.get_logger().warning(text)
        for name, spec in PARAMS.items():
            default = aliased.get(name, spec.default)
            if name == "always_on":  # its default follows mode and use_camera_info (declared)
                default = always_on_default(self._param_values(["mode", "use_camera_info"]))
            self.declare_parameter(name, default, descriptor(name, spec))
        values = self._param_values()
        errors = [e for n, v in values.items() if (e := parameter_error(n, v))]
        if errors:
            raise ValueError("invalid parameters: " + "; ".join(errors))
        return values

    def _input_callbacks(self) -> list[tuple[str, Callable[[Any], None]]]:
        """(base topic name, callback) of each image input of the mode: left and right, or one."""
        if self._mode == "stereo":
            return [
                ("left/image_raw", lambda m: self._on_stereo(m, LEFT)),
                ("right/image_raw", lambda m: self._on_stereo(m, RIGHT)),
            ]
        return [("image_raw", self._on_motion)]

    def _input_subscriptions(
        self, inputs: list[tuple[str, Callable[[Any], None]]], reliability: str
    ) -> list[InputSubscription]:
        """A subscription per image input, of the transport's message type."""
        from sepfm_ros.ros.msgs.raw_image import read_image  # raw Images: pixels in place

        msg_type = CompressedImage if self._transport == "compressed" else Image
        return [
            InputSubscription(
                self,
                input_topic(self, base, self._transport),
                msg_type,
                callback,
                reliability,
                on_lost=self._on_lost,
                on_incompatible=self._on_incompatible,
                on_created=self._on_subscribed,
                on_switched=self._on_qos_switch,
                parse=read_image if msg_type is Image else None,
            )
            for base, callback in inputs
        ]

    def _camera_info_inputs(self, values: dict[str, Any], bases: list[str]) -> Any:
        """The camera_info subscriptions beside the image inputs ``bases`` (a
        :class:`CameraInfoInputs`; None unless the ``use_camera_info`` parameter is set)."""
        if not values["use_camera_info"]:
            return None
        events = (self._on_lost, self._on_incompatible, self._on_subscribed)
        return CameraInfoInputs(self, bases, values["input_reliability"], *events)

    # ---------------------------------------------------------------- parameters
    def _param_values(self, names: Any = PARAMS) -> dict[str, Any]:
        return {name: self.get_parameter(name).value for name in names}

    def _validate_parameters(self, params: list[Parameter]) -> SetParametersResult:
        changes = {p.name: p.value for p in params}
        reasons = change_errors(self._param_values(), changes)
        if reasons:
            reason = "; ".join(reasons)
            self.get_logger().warning(f"parameter change rejected: {reason}")
            return SetParametersResult(successful=False, reason=reason)
        return SetParametersResult(successful=True)

    def _apply_parameters(self, params: list[Parameter]) -> None:
        values = self._param_values()
        self._always_on = bool(values["always_on"])  # the demand gate follows it
        if not self.configured:
            return  # read at configure
        from sepfm_ros.ros.session.session import configure_pairing

        self._session.configure(values)
        with self._lock:
            self._epipolar_lines = int(values["debug_epipolar_lines"])
            self._health.input_timeout_s = float(values["input_timeout_s"])
            configure_pairing(self._pairing, values)
        self.get_logger().info(
            "parameters set: " + ", ".join(f"{p.name}={p.value!r}" for p in params)
        )

    # ---------------------------------------------------------------- input callbacks
    def internal_error(self, kind: str, text: str) -> None:
        """An exception in a callback (:func:`guarded`): ERROR level in /diagnostics, logged."""
        self._health.problem(kind)
        self._log.log(kind, text)

    def _bad_input(self, kind: str, text: str) -> None:
        """Count a bad message by kind and log it (throttled per kind)."""
        self._health.problem(kind)
        self._log.log(kind, f"skipping bad input ({kind}): {text}")

    @guarded
    def _on_lost(self, topic: str, count: int) -> None:
        if count <= 0:
            return
        self._health.lost_samples(topic, count)
        advice = self._dds.lost_sample_advice()
        self._log.log(
            "lost_samples", f"{count} samples of {topic} lost in transport: {advice}", error=False
        )

    @guarded
    def _on_incompatible(self, topic: str, policy: str) -> None:
        self._health.problem("incompatible_qos")
        self._log.log(
            "incompatible_qos",
            f"a publisher of {topic} has an incompatible QoS ({policy}) and is not received; "
            "restart the node with input_reliability:=best_effort to receive every publisher",
        )

    @guarded
    def _on_subscribed(self, topic: str, reliability: str) -> None:
        self.get_logger().info(f"subscribed to {topic} ({reliability})")

    @guarded
    def _on_qos_switch(self, topic: str, old: str, new: str) -> None:
        """input_reliability auto recreated the subscription of ``topic`` with ``new``."""
        with self._lock:
            self._qos_switches[new] += 1
        self.get_logger().info(
            f"the publishers of {topic} changed: subscription switched from {old} to {new}, "
            "the reliability all of them match"
        )

    def _precheck(self, msg: Any, topic: str) -> bool:
        """Cheap field validation in the callback (no pixel access); False when skipped."""
        from sepfm_ros.ros.session.answer import precheck

        bad = precheck(msg)
        if bad is not None:
            self._bad_input(bad.kind, f"{topic}: {bad.text}")
            return False
        if getattr(msg, "step", None) == 0 and (note := self._zero_step.note(topic, msg)):
            self.get_logger().warning(note)
        self._health.frame_stamp(topic, stamp_ns(msg.header.stamp))  # frames missing before it
        return True

    def _offer(self, job: Job) -> None:
        self._health.pair_formed()
        self._scheduler.offer(job, job.received)

    def _stamp_jumped(self, topic: str, stamp: int) -> None:
        self._health.stamp_jump()
        self._health.restart_pairing()
        self._scheduler.reset_input()
        self._log.log(
            "stamp_jump",
            f"{topic} stamps jumped back to {stamp / 1e9:.3f} s (a looped bag, a restarted "
            "driver or simulator): pairing restarted from this frame",
            error=False,
        )

    @guarded
    def _on_stereo(self, msg: Any, side: int) -> None:
        topic = "left" if side == LEFT else "right"
        received = self._health.input(topic)
        if not self._precheck(msg, topic):
            return
        stamp = stamp_ns(msg.header.stamp)
        with self._lock:
            stereo = cast(StereoPairing[tuple[Any, float]], self._pairing)
            out: PairOutcome = stereo.add(side, Frame((msg, received), stamp))
            run = stereo.resets  # after a restart the same stamps may be other images
            offset = stereo.offset_ns()
        if offset is not None:
            self._health.stereo_offset(offset)
        if out.reset:
            self._stamp_jumped(topic, stamp)
        if out.pair is None:
            return
        (left, t_left), (right, t_right) = out.pair[0].item, out.pair[1].item
        ns_l, ns_r = out.pair[0].stamp_ns, out.pair[1].stamp_ns
        header = copy_header(left.header)
        job = Job(left, right, max(t_left, t_right), header, (run, "l", ns_l), (run, "r", ns_r))
        self._offer(job)
        self._corrected.pair_formed([left, right])  # while a correction is in force

    @guarded
    def _on_motion(self, msg: Any) -> None:
        received = self._health.input("image")
        if not self._precheck(msg, "image"):
            return
        stamp = stamp_ns(msg.header.stamp)
        with self._lock:
            motion = cast(MotionPairing[tuple[Any, float]], self._pairing)
            out: PairOutcome = motion.add(Frame((msg, received), stamp))
            run = motion.resets
        if out.reset:
            self._stamp_jumped("image", stamp)
        if out.late:
            self._bad_input("stamp_not_increasing", f"frame stamp {stamp} ns is not after the last")
            return
        if out.pair is None:
            return
        first = out.pair[0]
        self._offer(
            Job(
                first.item[0],
                msg,
                received,
                copy_header(msg.header),
                (run, first.stamp_ns),
                (run, stamp),
            )
        )

    # ---------------------------------------------------------------- workers
    def _match_loop(self) -> None:
        """Thread ``sepfm-match``: newest pair -> decoded images -> matches -> estimate thread."""
        while True:
            offered = self._scheduler.take_for_match()
            if offered is None:
                return
            job = offered.job
            t0 = time.monotonic()
            try:
                matched = self._match(job)
            except Exception as err:  # keep serving; count, log and answer
                matched = self._failed(job, self._internal_error_answer(job, err))
            if not isinstance(matched, MatchedJob):  # BadInput
                self._bad_input(matched.kind, matched.text)
                answer = self._session.failure(job.headers(), matched)
                matched = self._failed(job, answer)
            self._scheduler.put_matched(matched, time.monotonic() - t0)

    def _estimate_loop(self) -> None:
        """Thread ``sepfm-estimate``: matched pair -> estimate -> published outputs."""
        while True:
            taken = self._scheduler.take_for_estimate()
            if taken is None:
                return
            matched, t0 = taken
            try:
                if matched.failure is not None:
                    self._out.answer(matched.failure)
                else:
                    self._estimate_and_publish(matched)
            except Exception as err:  # keep serving; count, log and answer
                self._publish_answer(self._internal_error_answer(matched.job, err))
            self._scheduler.estimate_done(t0)

    def _internal_error_answer(self, job: Job, err: Exception) -> PairAnswer:
        """Count and log an unexpected error of a pair; its answer (STATUS_INTERNAL_ERROR)."""
        self._bad_input(internal_error_kind(err), internal_error_text(err))
        return self._session.internal_error(job.headers(), err)

    @staticmethod
    def _failed(job: Job, answer: PairAnswer) -> MatchedJob:
        """A pair that will not be estimated, with its failure record for the estimate thread."""
        now = time.monotonic()
        return MatchedJob(job, None, None, (now - job.received) * 1e3, now, answer)

    def _publish_answer(self, answer: PairAnswer) -> None:
        """Publish a pair's messages; a failure here (e.g. shutting down) never kills the worker."""
        try:
            self._out.answer(answer)
        except Exception as err:  # noqa: BLE001 - keep serving
            self._bad_input(internal_error_kind(err), f"cannot publish an answer: {err}")

    def _match(self, job: Job) -> MatchedJob | BadInput:
        from sepfm_ros.ros.session.answer import BadInput

        started = time.monotonic()
        wait_ms = (started - job.received) * 1e3
        decoded = self._session.decode(job.msg_a, job.msg_b, (job.key_a, job.key_b))
        if isinstance(decoded, BadInput):
            return decoded
        matched = self._session.match(decoded, job.key_a, job.key_b)
        return MatchedJob(job, matched, decoded.images, wait_ms, time.monotonic())

    def _camera_infos(self, job: Job) -> list[Any] | None:
        """The camera_info of each camera for the pair's images, matched by stamp (None: none
        yet, or camera_info not used); an image without one is counted and logged."""
        if self._camera_info is None:
            return None
        msgs = [job.msg_a, job.msg_b] if self._mode == "stereo" else [job.msg_b]
        slop_ns = int(round(float(self._session.values["sync_slop_s"]) * 1e9))
        return self._camera_info.for_images(msgs, slop_ns, self._log)

    def _log_cameras(self, update: CamerasUpdate | None) -> None:
        """Count and log unusable camera_info; log a calibration newly in use."""
        if update is None:
            return
        if update.error is not None:
            self._health.problem("camera_info_invalid")
            self._log.log("camera_info_invalid", f"camera_info unusable: {update.reason}")
        elif update.changed:
            self.get_logger().info(calibration_in_use_text(self._session.calibrated.calibration))

    def _estimate_and_publish(self, item: MatchedJob) -> None:
        from sepfm_ros.ros.session.answer import add_timings

        job = item.job
        queue_ms = (time.monotonic() - item.matched_at) * 1e3
        assert item.matched is not None  # failures are published as they are
        answer = self._session.answer_matched(
            job.headers(),
            item.matched,
            self._camera_infos(job),
            {"wait": item.wait_ms, "queue": queue_ms},
        )
        self._log_cameras(answer.cameras_update)
        if answer.estimate.bad_input_kind:  # the estimator refused the matches
            self._bad_input(answer.estimate.bad_input_kind, answer.estimate.status_text)
        if answer.calibration is not None:
            with self._lock:
                self._calib_status = answer.calibration
        latency_ms = (time.monotonic() - job.received) * 1e3
        add_timings(answer.estimate, {"latency": latency_ms})
        # the correction in force from this pair on (before its answer, which announces it)
        self._corrected.update(self._session.calibrated.calibration, [job.msg_a, job.msg_b])
        self._out.answer(answer, item.images, self._epipolar_lines)
        ok = answer.result is not None and answer.result.ok
        self._health.answered(latency_ms, item.wait_ms, answer.has_f, ok)

    # ---------------------------------------------------------------- health
    def health(self) -> dict[str, Any]:
        """The values of the /diagnostics report (rates over the last period)."""
        values = self._health.values()
        values.update(self._scheduler.snapshot())
        with self._lock:
            switches = dict(self._qos_switches)
        values.update(subscription_values(self._subs, self._health.topics, switches))
        values["dds_input_transport"] = self._dds.describe()
        if self._camera_info is not None:
            values.update(self._camera_info.diagnostic_values())
        # subscribers matched by the result publishers (the fewest over estimate and matches) and by
        # ~/debug_image (drawn on the estimate thread, after the answer, only for these)
        values.update(self._out.subscribers())
        values.update(self._corrected.diagnostic_values())
        # motion mode: each frame detected once (its features are cached by stamp)
        values["images_detected"] = self._session.pipeline.images_detected
        values["images_features_cached"] = self._session.pipeline.images_cached
        if self._mode == "stereo":
            with self._lock:
                stats = cast(StereoPairing[tuple[Any, float]], self._pairing).stats
                values["sync_unmatched"] = stats.unmatched + stats.evicted
                values["sync_late"] = stats.late
        return values

    @guarded
    def _check_level_change(self) -> None:
        """Report at once when one camera stalls or comes back (between periodic reports)."""
        stall = self._health.stall()
        if (stall is None) != (self._reported_stall is None):
            self._report_health()

    @guarded
    def _report_health(self) -> None:
        """The ``/diagnostics`` report: warming up (any state), or the health while active
        (idle: OK, no stall check); nothing while inactive or unconfigured."""
        if not self.kernels_ready:
            self._report_status(OK, WARMING_UP, {"lifecycle_state": state_name(self)})
            return
        if state_name(self) != "active":
            return
        release_free_memory()
        values = self.health()
        if self._demand.on:
            stall = self._health.stall()
            level, message = self._health.level(stall)
        else:
            stall, (level, message) = None, (OK, IDLE)
        self._reported_stall = stall
        self._report_status(level, message, values)

    def _report_status(self, level: int, message: str, values: dict[str, Any]) -> None:
        status = health_status(
            status_name(self.get_fully_qualified_name(), "node"),
            LEVEL_BYTES[level],
            message,
            values,
            self.get_fully_qualified_name(),
        )
        statuses = [status]
        with self._lock:
            if self._calib_status is not None:
                statuses.append(self._calib_status)
        stamp = self.get_clock().now().to_msg()
        self._diagnostics.publish(diagnostic_array(Header(stamp=stamp, frame_id=""), statuses))

    def shutdown(self) -> None:
        """Stop the worker threads (waits for the pairs in progress; none before configure)."""
        if not hasattr(self, "_scheduler"):
            return
        self._scheduler.stop()
        for worker in self._workers:
            worker.join(timeout=10.0)
