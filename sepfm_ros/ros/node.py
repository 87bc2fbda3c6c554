"""The live two-view geometry node ``sepfm``: images in, F, matches and diagnostics out.

Run it as ``sepfm_ros node --ros-args ...`` (or ``ros2 run sepfm_ros node --ros-args ...``).

Threading: the executor (single-threaded) only runs cheap callbacks: they validate a message's
fields, pair stereo stamps (:mod:`sepfm_ros.ros.sync`) and put the newest pair into a one-element
input slot. A pair still waiting there when a newer one arrives is replaced and counted as dropped,
so nothing queues without bound. The one exception: a pair that arrives while the node is idle, or
keeps up and its match thread is idle (waiting for input), is owed an answer and is never replaced;
the next pairs queue behind it in the slot. Without it, two pairs delivered together after a
transport delay (a reliable DDS reader recovering a lost fragment, a sender catching up after a
hiccup) lost the first one although the node was idle: 2-4 of 150 pairs of KITTI stereo at 5 Hz,
and 3 of 20 pairs of a bag replay on a loaded CI machine. Two worker threads then run the
:class:`~sepfm_ros.pipeline.pipeline.Pipeline` one pair apart, like a two-stage assembly line:

- ``sepfm-match`` takes the newest pair from the input slot, decodes the images, detects features
  (each frame once: cached by stamp; in stereo mode the right image on a helper thread
  ``sepfm-detect`` at the same time) and matches them (:meth:`Pipeline.match`, OpenCV and
  compiled code that release the GIL), and hands the matches over in a one-element slot;
- ``sepfm-estimate`` runs the estimator on them (:meth:`Pipeline.estimate`) and publishes; the
  ``max_samples`` parameter caps its RANSAC samples, so a pair without consensus (a few dozen
  matches, most of them wrong) cannot hold it for long.

While the node keeps up (pairs arrive no faster than it processes them), a pair that comes while
the previous one is being estimated is matched from a few milliseconds before the estimator is
expected to finish (recent median of its duration), so the two stages overlap only briefly.
While saturated (recent mean input period below the recent median matching plus estimation
time, :func:`is_saturated`) the node serves the freshest pair with the least contention:

- a pair's two stages run one after the other, never overlapping: matching pair n+1 during pair
  n's estimation (as before 2026-11-23) ran both stages, the executor and the sender on 2 cores at
  once, each stage slower (estimation p95 15-17 ms against 10-12 ms one after the other);
- the match thread starts on the pair in the slot only if it is at most a quarter of the input
  period old; otherwise it waits for the next pair (:func:`fresher_pair_wait`): that answer comes
  out at about the same time and is a period fresher. Taking whatever waited in the slot made the
  pair's age when taken p95 10-13 ms (one period) under input at twice the processing rate; now
  p95 2 ms;
- the owed-pair rule above holds only while the node is wholly idle (pairs are dropped anyway; a
  burst then keeps its newest).

With both, the p95 latency under input at twice the processing rate fell from 1.46-2.03x its
unloaded value (7 runs) to 1.03-1.69x (12 runs, median 1.28), answering about a tenth fewer
pairs (2424-2799 against 2730-3086 a minute; 2026-11-23).

Each pair goes through exactly the calls of :meth:`Pipeline.process` with the config it was matched
with, so the results equal offline processing. Threads of our own are used rather than a
MultiThreadedExecutor because the latest-only slots are needed anyway and running several
estimations at once on 2 cores would only raise everyone's latency.

For the same reason :func:`limit_thread_pools` keeps the native thread pools to one thread each:
OpenCV's own pool and numpy's OpenBLAS, whose idle workers otherwise spin on the second core
after every large product and take it from the match thread.
"""

from __future__ import annotations

import argparse
import os
import signal
import statistics
import threading
import time
import traceback
from collections import Counter, deque
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    ParameterType,
    SetParametersResult,
)
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from rclpy.qos_overriding_options import QoSOverridingOptions
from sensor_msgs.msg import CompressedImage, Image, PointCloud2
from std_msgs.msg import Header
from threadpoolctl import threadpool_limits

from sepfm_ros.geometry import METHODS
from sepfm_ros.pipeline.compiled import warm_up
from sepfm_ros.pipeline.drawing import draw_result
from sepfm_ros.pipeline.features import FEATURES
from sepfm_ros.pipeline.pipeline import (
    MatchedPair,
    Pipeline,
    PipelineConfig,
    name_native_thread,
)
from sepfm_ros.ros.image_conversion import (
    ImageDecodeError,
    check_compressed,
    check_image,
    message_to_numpy,
    numpy_to_image,
)
from sepfm_ros.ros.memory import (
    configure_malloc,
    release_free_memory,
    use_node_dds_profiles,
)
from sepfm_ros.ros.messages import (
    copy_header,
    diagnostic_array,
    estimate_info,
    failure_info,
    fundamental_to_image,
    health_status,
    result_to_pointcloud2,
    stamp_ns,
)
from sepfm_ros.ros.replay import raise_keyboard_interrupt
from sepfm_ros.ros.sync import LEFT, RIGHT, ApproximateTimeSync

NODE_NAME = "sepfm"
MODES = ("stereo", "motion")
TRANSPORTS = ("raw", "compressed")
# Estimator option that the hough_width_px parameter sets (0 = leave the estimator's default).
HOUGH_WIDTH_OPTION = "hough_width"
# Estimator option that the max_samples parameter sets.
MAX_SAMPLES_OPTION = "max_samples"


@dataclass(frozen=True)
class ParamSpec:
    """One node parameter: default, description, and either a numeric range or choices."""

    default: Any
    description: str
    low: float | None = None
    high: float | None = None
    choices: tuple[str, ...] = ()
    read_only: bool = False


PARAMS: dict[str, ParamSpec] = {
    "mode": ParamSpec(
        "stereo",
        "stereo: pair left/image_raw with right/image_raw by stamp; motion: frame t-gap with t",
        choices=MODES,
        read_only=True,
    ),
    "transport": ParamSpec(
        "raw",
        "raw: sensor_msgs/Image; compressed: sensor_msgs/CompressedImage on <topic>/compressed",
        choices=TRANSPORTS,
        read_only=True,
    ),
    "sync_slop_s": ParamSpec(
        0.005, "stereo: largest stamp difference of a pair, s (0 = exact)", 0.0, 1.0
    ),
    "sync_queue_size": ParamSpec(10, "stereo: unpaired messages kept per side", 1, 1000),
    "frame_gap": ParamSpec(1, "motion: F between frame t - frame_gap and frame t", 1, 100),
    "features": ParamSpec("orb", "feature detector/descriptor", choices=FEATURES),
    "max_features": ParamSpec(1000, "keypoints per image (orb, sift)", 8, 100000),
    "ratio": ParamSpec(0.8, "Lowe ratio-test bound for matches", 0.05, 1.0),
    "max_matches": ParamSpec(0, "keep at most this many best matches (0 = all)", 0, 100000),
    "method": ParamSpec("sep5", "estimator method", choices=METHODS),
    "threshold_px": ParamSpec(
        1.0, "inlier threshold, symmetric epipolar distance, px", 0.01, 100.0
    ),
    "confidence": ParamSpec(0.99, "RANSAC confidence", 0.5, 0.999999),
    "max_samples": ParamSpec(
        1000,
        "cap on the estimator's RANSAC samples per pair (bounds its time on a pair without"
        " consensus; ample for ORB matches of real pairs)",
        10,
        1_000_000,
    ),
    "hough_width_px": ParamSpec(
        0, "working width of the line-pair (Hough) search, px (0 = estimator default)", 0, 8192
    ),
    "seed": ParamSpec(
        0, "seed of the estimator's random choices (same for every pair)", 0, 2**31 - 1
    ),
    "publish_unreliable": ParamSpec(
        True,
        "also publish F when the estimator flags it unreliable (status not ok, e.g. a dominant"
        " plane); ~/estimate_info then carries the reason at WARN level",
    ),
    "debug_epipolar_lines": ParamSpec(8, "epipolar lines drawn on ~/debug_image", 0, 100),
    "diagnostics_period_s": ParamSpec(
        1.0, "period of the /diagnostics health report, s", 0.1, 60.0, read_only=True
    ),
    "input_timeout_s": ParamSpec(
        0.5,
        "stereo: a camera silent this much longer than the other one turns /diagnostics to WARN"
        " (reported at once, and back to OK when it returns)",
        0.05,
        60.0,
    ),
}

# While the node keeps up, the match thread starts this much before the estimator is expected to
# finish; it never waits longer than MAX_MATCH_DELAY_S at a time (see _match_start_delay).
MATCH_START_MARGIN_S = 0.004
MAX_MATCH_DELAY_S = 0.05
# While saturated (see fresher_pair_wait): a pair is fresh enough to start on when its age is at
# most this share of the input period; otherwise the next pair is awaited until it is due plus
# this share of the period (its arrival jitters), and the stale pair is taken if none comes.
FRESH_AGE_SHARE = 0.25
FRESHER_WAIT_SLACK_SHARE = 0.5

# How often input silence is checked (a change of the health level is reported at once).
STALL_CHECK_PERIOD_S = 0.1

PIPELINE_PARAMS = {
    "features": "features",
    "max_features": "max_features",
    "ratio": "ratio",
    "max_matches": "max_matches",
    "method": "method",
    "threshold_px": "threshold_px",
    "confidence": "confidence",
    "seed": "seed",
}


def _descriptor(name: str, spec: ParamSpec) -> ParameterDescriptor:
    extra = f" (one of: {', '.join(spec.choices)})" if spec.choices else ""
    desc = ParameterDescriptor(
        name=name, description=spec.description + extra, read_only=spec.read_only
    )
    if isinstance(spec.default, bool):
        desc.type = ParameterType.PARAMETER_BOOL
    elif isinstance(spec.default, str):
        desc.type = ParameterType.PARAMETER_STRING
    elif isinstance(spec.default, int):
        desc.type = ParameterType.PARAMETER_INTEGER
        desc.integer_range = [
            IntegerRange(from_value=int(spec.low), to_value=int(spec.high), step=1)
        ]
    else:
        desc.type = ParameterType.PARAMETER_DOUBLE
        desc.floating_point_range = [
            FloatingPointRange(from_value=float(spec.low), to_value=float(spec.high), step=0.0)
        ]
    if spec.choices:
        desc.additional_constraints = "one of: " + ", ".join(spec.choices)
    return desc


def parameter_error(name: str, value: Any) -> str | None:
    """Why ``value`` is not acceptable for parameter ``name`` (None when it is)."""
    spec = PARAMS.get(name)
    if spec is None:
        return None  # not ours (e.g. use_sim_time, qos overrides)
    if spec.choices:
        if value not in spec.choices:
            return f"{name} must be one of {', '.join(spec.choices)}; got {value!r}"
        return None
    if isinstance(spec.default, bool):
        return None if isinstance(value, bool) else f"{name} must be true or false; got {value!r}"
    if isinstance(value, bool) or not isinstance(value, int | float):
        return f"{name} must be a number; got {value!r}"
    if not spec.low <= value <= spec.high:
        return f"{name} must be in [{spec.low}, {spec.high}]; got {value}"
    return None


def pipeline_config(values: dict[str, Any]) -> PipelineConfig:
    """Node parameter values -> PipelineConfig (ValueError when invalid)."""
    options = {MAX_SAMPLES_OPTION: int(values.get("max_samples", PARAMS["max_samples"].default))}
    if int(values.get("hough_width_px", 0)) > 0:
        options[HOUGH_WIDTH_OPTION] = int(values["hough_width_px"])
    kwargs = {field: values[param] for param, field in PIPELINE_PARAMS.items() if param in values}
    return PipelineConfig(**kwargs, estimator_options=options)


@dataclass
class Job:
    """A pair waiting for the worker: a = left/earlier, b = right/current."""

    msg_a: Any
    msg_b: Any
    received: float  # time.monotonic() at receipt of the newer message
    header: Header  # header of the newer image (copied to every output)
    key_a: Any
    key_b: Any


class RecentMedian:
    """Median of a stage's last few durations (seconds): robust to one slow pair."""

    def __init__(self, size: int = 9, warmup: int = 3) -> None:
        self._values: deque[float] = deque(maxlen=size)
        self._warmup = warmup
        self.value = 0.0

    @property
    def ready(self) -> bool:
        return len(self._values) >= self._warmup

    def add(self, seconds: float) -> None:
        self._values.append(seconds)
        self.value = statistics.median(self._values)


class RecentPeriod:
    """Mean time between the last few events (seconds): the input period. A mean over a span,
    not a median of intervals, so that pairs delivered in bursts (two at once after a transport
    delay) do not pass for a fast input."""

    def __init__(self, size: int = 9, warmup: int = 4) -> None:
        self._times: deque[float] = deque(maxlen=size)
        self._warmup = warmup
        self.value = 0.0

    @property
    def ready(self) -> bool:
        return len(self._times) >= self._warmup

    def add(self, t: float) -> None:
        """Record an event at monotonic time ``t`` (s)."""
        self._times.append(t)
        if len(self._times) > 1:
            self.value = (self._times[-1] - self._times[0]) / (len(self._times) - 1)


@dataclass
class MatchedJob:
    """A matched pair waiting for the estimate thread."""

    job: Job
    matched: MatchedPair
    images: tuple[np.ndarray, np.ndarray]  # decoded a, b (for ~/debug_image)
    wait_ms: float  # receipt -> start of processing (decode)
    matched_at: float  # time.monotonic() when matching ended


def limit_thread_pools(threads: int = 1) -> None:
    """Run OpenCV's and the BLAS's internal parallel loops on ``threads`` threads (process-wide).

    The node already runs two worker threads (see the module docstring) on machines with few
    cores; native pools on top of them only oversubscribe the cores (OpenBLAS workers also
    busy-wait after each call). Results do not change: only how the work is scheduled.
    """
    cv2.setNumThreads(int(threads))
    threadpool_limits(limits=int(threads), user_api="blas")


def is_saturated(period_s: float, processing_s: float) -> bool:
    """True when pairs arrive faster than the node processes them one after the other.

    Args:
        period_s: recent mean time between input pairs, s.
        processing_s: recent median time of a pair's matching plus estimation, s.
    """
    return period_s < processing_s


def fresher_pair_wait(age_s: float, period_s: float) -> float:
    """Seconds to wait for the next input pair instead of starting on a pair ``age_s`` old.

    For a saturated node (pairs are dropped anyway): a pair at most FRESH_AGE_SHARE of the
    input period ``period_s`` old is taken at once (0.0); an older one is passed over until the
    next pair is due, plus FRESHER_WAIT_SLACK_SHARE of a period for its arrival jitter. The
    latency of an answer counts from the receipt of its pair, so an answer to the next pair
    comes out at about the same time as one to the stale pair would, but a period fresher.
    """
    if age_s <= FRESH_AGE_SHARE * period_s:
        return 0.0
    return max(period_s - age_s, 0.0) + FRESHER_WAIT_SLACK_SHARE * period_s


def _percentile(values: list[float], q: float) -> float:
    return float(np.percentile(values, q)) if values else float("nan")


class SepfmNode(Node):
    """The ``sepfm`` node (see the module docstring for the threading model)."""

    def __init__(self, node_name: str = NODE_NAME, **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        for name, spec in PARAMS.items():
            self.declare_parameter(name, spec.default, _descriptor(name, spec))
        values = self._param_values()
        errors = [e for n, v in values.items() if (e := parameter_error(n, v))]
        if errors:
            raise ValueError("invalid parameters: " + "; ".join(errors))
        self._mode = values["mode"]
        self._transport = values["transport"]

        self._lock = threading.Lock()
        self._cond = threading.Condition(self._lock)
        self._slot: Job | None = None  # newest pair, waiting for the match thread
        self._owed: Job | None = None  # a pair that arrived while the match thread was idle
        self._match_idle = False  # the match thread waits for input (no pair pending)
        self._matched: MatchedJob | None = None  # matched pair, waiting for the estimate thread
        self._estimating_since: float | None = None  # monotonic start of the current estimate
        self._match_s = RecentMedian()  # seconds per stage, to time the start of matching
        self._estimate_s = RecentMedian()
        self._period_s = RecentPeriod()  # seconds between offered pairs (the input period)
        self._passed_over: Job | None = None  # a pair kept waiting for a fresher one, once
        self._stop = False
        self._pending_config: PipelineConfig | None = None
        self._pipeline = Pipeline(pipeline_config(values), cache_size=8, parallel_detect=True)
        self._epipolar_lines = int(values["debug_epipolar_lines"])
        self._publish_unreliable = bool(values["publish_unreliable"])
        self._sync: ApproximateTimeSync[tuple[Any, float]] = ApproximateTimeSync(
            int(round(values["sync_slop_s"] * 1e9)), int(values["sync_queue_size"])
        )
        self._frame_gap = int(values["frame_gap"])
        self._history: deque[tuple[Any, float, int]] = deque(maxlen=self._frame_gap + 1)

        # counters (under self._lock)
        self._received: Counter[str] = Counter()
        self._published = 0
        self._failed = 0
        self._dropped = 0
        self._pairs = 0
        self._errors: Counter[str] = Counter()
        self._logged_kinds: set[str] = set()
        self._latency_ms: deque[float] = deque(maxlen=500)
        self._wait_ms: deque[float] = deque(maxlen=500)
        self._max_wait_ms = 0.0
        self._last_report = (time.monotonic(), Counter(), 0)
        self._last_input: dict[str, float] = {}  # topic -> time.monotonic() of the last message
        self._input_timeout_s = float(values["input_timeout_s"])
        self._reported_stall: str | None = None  # stall reason of the last health report

        reliable = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self._pub_f = self.create_publisher(Image, "~/fundamental", reliable)
        self._pub_matches = self.create_publisher(PointCloud2, "~/matches", reliable)
        self._pub_info = self.create_publisher(DiagnosticArray, "~/estimate_info", reliable)
        self._pub_debug = self.create_publisher(Image, "~/debug_image", reliable)
        self._pub_diag = self.create_publisher(DiagnosticArray, "/diagnostics", reliable)

        msg_type = CompressedImage if self._transport == "compressed" else Image
        suffix = "/compressed" if self._transport == "compressed" else ""
        overrides = QoSOverridingOptions.with_default_policies()
        if self._mode == "stereo":
            topics = {"left": "left/image_raw", "right": "right/image_raw"}
            self._subs = [
                self.create_subscription(
                    msg_type,
                    topics["left"] + suffix,
                    lambda m: self._on_stereo(m, LEFT),
                    qos_profile_sensor_data,
                    qos_overriding_options=overrides,
                ),
                self.create_subscription(
                    msg_type,
                    topics["right"] + suffix,
                    lambda m: self._on_stereo(m, RIGHT),
                    qos_profile_sensor_data,
                    qos_overriding_options=overrides,
                ),
            ]
        else:
            self._subs = [
                self.create_subscription(
                    msg_type,
                    "image_raw" + suffix,
                    self._on_motion,
                    qos_profile_sensor_data,
                    qos_overriding_options=overrides,
                )
            ]
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        self._diag_timer = self.create_timer(values["diagnostics_period_s"], self._report_health)
        self._stall_timer = self.create_timer(STALL_CHECK_PERIOD_S, self._check_level_change)
        self._workers = [
            threading.Thread(target=self._match_loop, name="sepfm-match", daemon=True),
            threading.Thread(target=self._estimate_loop, name="sepfm-estimate", daemon=True),
        ]
        for worker in self._workers:
            worker.start()
        self.get_logger().info(
            f"{self._mode} mode, {self._transport} transport, listening on "
            f"{', '.join(s.topic_name for s in self._subs)}; {self._pipeline.config}"
        )

    # ---------------------------------------------------------------- parameters
    def _param_values(self) -> dict[str, Any]:
        return {name: self.get_parameter(name).value for name in PARAMS}

    def _validate_parameters(self, params: list[Parameter]) -> SetParametersResult:
        values = self._param_values()
        reasons = []
        for p in params:
            if p.name in PARAMS and PARAMS[p.name].read_only:
                reasons.append(f"{p.name} is read-only (set it at start-up)")
                continue
            error = parameter_error(p.name, p.value)
            if error:
                reasons.append(error)
            elif p.name in PARAMS:
                values[p.name] = p.value
        if not reasons:
            try:
                pipeline_config(values)
            except ValueError as err:
                reasons.append(str(err))
        if reasons:
            reason = "; ".join(reasons)
            self.get_logger().warning(f"parameter change rejected: {reason}")
            return SetParametersResult(successful=False, reason=reason)
        return SetParametersResult(successful=True)

    def _apply_parameters(self, params: list[Parameter]) -> None:
        values = self._param_values()
        config = pipeline_config(values)
        with self._lock:
            self._pending_config = config
            self._epipolar_lines = int(values["debug_epipolar_lines"])
            self._publish_unreliable = bool(values["publish_unreliable"])
            self._input_timeout_s = float(values["input_timeout_s"])
            self._sync.configure(
                int(round(values["sync_slop_s"] * 1e9)), int(values["sync_queue_size"])
            )
            if int(values["frame_gap"]) != self._frame_gap:
                self._frame_gap = int(values["frame_gap"])
                self._history = deque(self._history, maxlen=self._frame_gap + 1)
        self.get_logger().info(
            "parameters set: " + ", ".join(f"{p.name}={p.value!r}" for p in params)
        )

    # ---------------------------------------------------------------- input callbacks
    def _bad_input(self, kind: str, text: str) -> None:
        """Count a bad message by kind and log it the first time its kind occurs."""
        with self._lock:
            self._errors[kind] += 1
            first = kind not in self._logged_kinds
            self._logged_kinds.add(kind)
        if first:
            self.get_logger().error(
                f"skipping bad input ({kind}): {text}"
                " [logged once per kind, counted in /diagnostics]"
            )

    def _precheck(self, msg: Any, topic: str) -> bool:
        """Cheap field validation in the callback (no pixel access); False when skipped."""
        try:
            if self._transport == "raw":
                check_image(msg)
            else:
                check_compressed(msg)
        except ImageDecodeError as err:
            self._bad_input(err.kind, f"{topic}: {err}")
            return False
        return True

    def _offer(self, job: Job) -> None:
        with self._cond:
            self._period_s.add(job.received)
            node_idle = self._estimating_since is None
            if self._match_idle and self._owed is None and (node_idle or not self._saturated()):
                self._owed = job  # answered even if newer pairs arrive before it is taken
                self._match_idle = False
            else:
                if self._slot is not None:
                    self._dropped += 1
                self._slot = job
            self._pairs += 1
            self._cond.notify_all()  # both worker threads wait on this condition

    def _on_stereo(self, msg: Any, side: int) -> None:
        received = time.monotonic()
        topic = "left" if side == LEFT else "right"
        with self._lock:
            self._received[topic] += 1
            self._last_input[topic] = received
        if not self._precheck(msg, topic):
            return
        with self._lock:
            pair = self._sync.add(side, stamp_ns(msg.header.stamp), (msg, received))
        if pair is None:
            return
        (left, t_left), (right, t_right) = pair
        if self._transport == "raw" and (left.width, left.height) != (right.width, right.height):
            self._bad_input(
                "size_mismatch",
                f"left {left.width}x{left.height} and right {right.width}x{right.height} differ",
            )
            return
        ns_l, ns_r = stamp_ns(left.header.stamp), stamp_ns(right.header.stamp)
        received = max(t_left, t_right)
        header = copy_header(left.header)
        self._offer(Job(left, right, received, header, ("l", ns_l), ("r", ns_r)))

    def _on_motion(self, msg: Any) -> None:
        received = time.monotonic()
        with self._lock:
            self._received["image"] += 1
            self._last_input["image"] = received
        if not self._precheck(msg, "image"):
            return
        stamp = stamp_ns(msg.header.stamp)
        with self._lock:
            if self._history and stamp <= self._history[-1][2]:
                late = True
            else:
                late = False
                self._history.append((msg, received, stamp))
                ready = len(self._history) == self._history.maxlen
                first = self._history[0]
        if late:
            self._bad_input("stamp_not_increasing", f"frame stamp {stamp} ns is not after the last")
            return
        if not ready:
            return
        self._offer(Job(first[0], msg, received, copy_header(msg.header), first[2], stamp))

    # ---------------------------------------------------------------- worker
    def _match_loop(self) -> None:
        """Thread ``sepfm-match``: newest pair -> decoded images -> matches -> hand-over slot."""
        name_native_thread()
        while True:
            with self._cond:
                while not self._stop:
                    pending = self._owed is not None or self._slot is not None
                    if not pending or self._matched is not None:
                        self._match_idle = not pending
                        self._cond.wait()
                        continue
                    self._match_idle = False
                    now = time.monotonic()
                    delay = self._match_start_delay(now)
                    if delay <= 0.0 and self._owed is None:
                        delay = self._fresher_pair_delay(now)
                    if delay <= 0.0:
                        break
                    self._cond.wait(timeout=delay)  # a newer pair may arrive meanwhile
                if self._stop:
                    return
                if self._owed is not None:
                    job, self._owed = self._owed, None
                else:
                    job, self._slot = self._slot, None
                config, self._pending_config = self._pending_config, None
            if config is not None:
                self._pipeline.configure(config)
            t0 = time.monotonic()
            try:
                matched = self._match(job)
            except ImageDecodeError as err:
                self._bad_input(err.kind, str(err))
                self._publish_failure(job, err.kind, str(err))
                continue
            except Exception as err:  # keep serving; count and log once per kind
                self._internal_error(job, err)
                continue
            with self._cond:
                self._match_s.add(time.monotonic() - t0)
                self._matched = matched
                self._cond.notify_all()

    def _saturated(self) -> bool:
        """:func:`is_saturated` on the recent timings (False until they are known). Caller holds
        the lock."""
        if not (self._period_s.ready and self._match_s.ready and self._estimate_s.ready):
            return False
        return is_saturated(self._period_s.value, self._match_s.value + self._estimate_s.value)

    def _match_start_delay(self, now: float) -> float:
        """Seconds the match thread should still wait before taking the newest pair (<= 0: go).

        Saturated: not before the estimator is done (it notifies), so that a pair's two stages
        never compete for the cores. Keeping up (a pair came while the previous one is being
        estimated): the match thread starts a margin before the estimator's expected end
        (running median of its duration), so that the estimator does not wait for it and the
        two overlap only briefly. Caller holds the lock.
        """
        if self._estimating_since is None:
            return 0.0
        if self._saturated():
            return MAX_MATCH_DELAY_S
        if not self._estimate_s.ready:
            return 0.0
        remaining = self._estimate_s.value - (now - self._estimating_since)
        return min(remaining - MATCH_START_MARGIN_S, MAX_MATCH_DELAY_S)

    def _fresher_pair_delay(self, now: float) -> float:
        """Seconds to wait for a pair newer than the one in the slot (<= 0: take this one).

        Only while saturated (:func:`fresher_pair_wait`; at a rate the node keeps up with, every
        pair is answered, even one that waited behind a slow pair). A pair is passed over once:
        if no newer one comes, it is processed after the wait. Caller holds the lock.
        """
        job = self._slot
        if job is None or job is self._passed_over or not self._saturated():
            return 0.0
        wait = fresher_pair_wait(now - job.received, self._period_s.value)
        if wait > 0.0:
            self._passed_over = job
        return wait

    def _estimate_loop(self) -> None:
        """Thread ``sepfm-estimate``: matched pair -> estimate -> published outputs."""
        name_native_thread()
        while True:
            with self._cond:
                while self._matched is None and not self._stop:
                    self._cond.wait()
                if self._stop:
                    return
                matched, self._matched = self._matched, None
                self._estimating_since = t0 = time.monotonic()
                self._cond.notify_all()  # the match thread may prepare the next pair now
            try:
                self._estimate_and_publish(matched)
            except Exception as err:  # keep serving; count and log once per kind
                self._internal_error(matched.job, err)
            with self._cond:
                self._estimate_s.add(time.monotonic() - t0)
                self._estimating_since = None
                self._cond.notify_all()

    def _internal_error(self, job: Job, err: Exception) -> None:
        kind = f"internal_{type(err).__name__}"
        self._bad_input(kind, "".join(traceback.format_exception(err)))
        self._publish_failure(job, kind, f"{type(err).__name__}: {err}")

    def _publish_failure(self, job: Job, kind: str, reason: str) -> None:
        """Answer a pair that could not be processed on ~/estimate_info (ERROR level)."""
        try:
            config = self._pipeline.config
            self._pub_info.publish(
                failure_info(
                    job.header,
                    job.msg_a.header.stamp,
                    job.msg_b.header.stamp,
                    reason,
                    kind,
                    config.features,
                    config.method,
                    node_name=self.get_fully_qualified_name(),
                )
            )
        except Exception as err:  # noqa: BLE001 - e.g. shutting down; never kill the worker
            self._bad_input(f"internal_{type(err).__name__}", f"cannot publish a failure: {err}")

    def _match(self, job: Job) -> MatchedJob:
        started = time.monotonic()
        wait_ms = (started - job.received) * 1e3
        t0 = time.perf_counter()
        image_a = message_to_numpy(job.msg_a, "mono8")
        image_b = message_to_numpy(job.msg_b, "mono8")
        decode_ms = (time.perf_counter() - t0) * 1e3
        if image_a.shape != image_b.shape:
            raise ImageDecodeError(
                "size_mismatch",
                f"images of a pair differ in size: {image_a.shape[::-1]} vs {image_b.shape[::-1]}",
            )
        matched = self._pipeline.match(
            image_a, image_b, job.key_a, job.key_b, prior_timings_ms={"decode": decode_ms}
        )
        with self._lock:
            self._wait_ms.append(wait_ms)
            self._max_wait_ms = max(self._max_wait_ms, wait_ms)
        return MatchedJob(job, matched, (image_a, image_b), wait_ms, time.monotonic())

    def _estimate_and_publish(self, item: MatchedJob) -> None:
        job = item.job
        queue_ms = (time.monotonic() - item.matched_at) * 1e3
        result = self._pipeline.estimate(item.matched)
        t0 = time.perf_counter()
        header = job.header
        with self._lock:
            publish_unreliable = self._publish_unreliable
        published = result.estimate.F is not None and (result.ok or publish_unreliable)
        if published:
            self._pub_f.publish(fundamental_to_image(result.estimate.F, header))
        self._pub_matches.publish(result_to_pointcloud2(result, header))
        publish_ms = (time.perf_counter() - t0) * 1e3
        latency_ms = (time.monotonic() - job.received) * 1e3
        extra = {"publish": publish_ms, "wait": item.wait_ms, "queue": queue_ms}
        self._pub_info.publish(
            estimate_info(
                result,
                header,
                job.msg_a.header.stamp,
                job.msg_b.header.stamp,
                item.matched.config.features,
                extra_timings_ms={**extra, "latency": latency_ms},
                node_name=self.get_fully_qualified_name(),
            )
        )
        if self._pub_debug.get_subscription_count() > 0:
            with self._lock:
                n_lines = self._epipolar_lines
            canvas = draw_result(*item.images, result, n_lines)
            self._pub_debug.publish(numpy_to_image(canvas, "bgr8", header))
        with self._lock:
            self._latency_ms.append(latency_ms)
            if published:
                self._published += 1
            if not result.ok:
                self._failed += 1

    # ---------------------------------------------------------------- health
    def health(self) -> dict[str, Any]:
        """The values of the /diagnostics report (rates over the last period)."""
        now = time.monotonic()
        with self._lock:
            t_last, received_last, published_last = self._last_report
            dt = max(now - t_last, 1e-6)
            values: dict[str, Any] = {}
            for topic in ("left", "right") if self._mode == "stereo" else ("image",):
                rate = (self._received[topic] - received_last[topic]) / dt
                values[f"input_rate_{topic}_hz"] = rate
                values[f"received_{topic}"] = self._received[topic]
            # publishers matched by the input subscriptions (the fewest over the inputs): a player
            # can wait for this before sending, since a message sent before matching is lost
            values["input_publishers"] = min(s.get_publisher_count() for s in self._subs)
            # and subscribers matched by the result publishers (the fewest over F, matches, info)
            values["output_subscribers"] = min(
                p.get_subscription_count() for p in (self._pub_f, self._pub_matches, self._pub_info)
            )
            # ~/debug_image is drawn (on the estimate thread, after the answer) only for these
            values["debug_image_subscribers"] = self._pub_debug.get_subscription_count()
            # pairs arrive faster than processed: the freshest are served, the rest dropped
            values["saturated"] = self._saturated()
            values["output_rate_hz"] = (self._published - published_last) / dt
            values["published"] = self._published
            values["estimation_not_ok"] = self._failed
            values["synchronized_pairs"] = self._pairs
            values["dropped_pairs"] = self._dropped
            # motion mode: each frame detected once (its features are cached by stamp)
            values["images_detected"] = self._pipeline.images_detected
            values["images_features_cached"] = self._pipeline.images_cached
            if self._mode == "stereo":
                values["sync_unmatched"] = self._sync.stats.unmatched + self._sync.stats.evicted
                values["sync_late"] = self._sync.stats.late
            lat = list(self._latency_ms)
            values["latency_p50_ms"] = _percentile(lat, 50)
            values["latency_p95_ms"] = _percentile(lat, 95)
            values["wait_max_ms"] = self._max_wait_ms
            values["errors_total"] = sum(self._errors.values())
            for kind, count in sorted(self._errors.items()):
                values[f"errors_{kind}"] = count
            for topic, age in self._input_ages(now).items():
                values[f"input_age_{topic}_s"] = age
            self._last_report = (now, Counter(self._received), self._published)
        return values

    def _input_ages(self, now: float) -> dict[str, float]:
        """topic -> seconds since its last message (only topics that have sent one)."""
        return {topic: now - t for topic, t in self._last_input.items()}

    def _stall(self, now: float) -> str | None:
        """Why the input looks stalled, or None (caller holds the lock)."""
        ages = self._input_ages(now)
        timeout = self._input_timeout_s
        if self._mode == "stereo":
            for topic, other in (("left", "right"), ("right", "left")):
                if topic not in ages and other in ages and ages[other] < timeout:
                    since = now - min(self._last_input.values())
                    if since > timeout:
                        return f"no {topic} images yet, {other} images arriving"
                if topic in ages and other in ages and ages[topic] - ages[other] > timeout:
                    return (
                        f"{topic} camera silent for {ages[topic]:.1f} s while {other} images "
                        "arrive: no pairs"
                    )
        return None

    def _level(self, values: dict[str, Any], stall: str | None) -> tuple[bytes, str]:
        if stall is not None:
            return DiagnosticStatus.WARN, stall
        if values["errors_total"]:
            return DiagnosticStatus.WARN, f"{values['errors_total']} bad inputs skipped"
        return DiagnosticStatus.OK, "ok"

    def _check_level_change(self) -> None:
        """Report at once when one camera stalls or comes back (between periodic reports)."""
        with self._lock:
            stall = self._stall(time.monotonic())
        if (stall is None) != (self._reported_stall is None):
            self._report_health()

    def _report_health(self) -> None:
        release_free_memory()
        values = self.health()
        with self._lock:
            stall = self._stall(time.monotonic())
        level, message = self._level(values, stall)
        self._reported_stall = stall
        status = health_status(
            f"{self.get_name()}: node", level, message, values, self.get_fully_qualified_name()
        )
        header = Header(stamp=self.get_clock().now().to_msg(), frame_id="")
        self._pub_diag.publish(diagnostic_array(header, [status]))

    def shutdown(self) -> None:
        """Stop the worker threads (waits for the pairs in progress)."""
        with self._cond:
            self._stop = True
            self._cond.notify_all()
        for worker in self._workers:
            worker.join(timeout=10.0)


def _usage() -> str:
    lines = [
        "The sepfm node: subscribes to left/image_raw + right/image_raw (mode:=stereo) or",
        "image_raw (mode:=motion), publishes ~/fundamental (64FC1 3x3 Image), ~/matches",
        "(PointCloud2), ~/estimate_info and /diagnostics (DiagnosticArray), ~/debug_image.",
        "",
        "parameters:",
    ]
    for name, spec in PARAMS.items():
        if spec.choices:
            rng = f" one of {'/'.join(spec.choices)}"
        elif isinstance(spec.default, bool):
            rng = " true/false"
        else:
            rng = f" [{spec.low}, {spec.high}]"
        ro = " (read-only)" if spec.read_only else ""
        lines.append(f"  {name} = {spec.default!r}{rng}{ro}: {spec.description}")
    return "\n".join(lines)


def warm_up_interruptibly() -> float | None:
    """:func:`warm_up` in a thread, so SIGINT / SIGTERM stop the node while kernels compile.

    numba compiles on: a KeyboardInterrupt raised in the compiling thread is lost. Returns the
    seconds spent, or None when interrupted (the thread is left to the process's exit).
    """
    done: dict[str, float] = {}
    thread = threading.Thread(
        target=lambda: done.update(s=warm_up()), name="kernel-warm-up", daemon=True
    )
    previous = signal.signal(signal.SIGTERM, raise_keyboard_interrupt)
    try:
        thread.start()
        while thread.is_alive():
            thread.join(0.1)
    except KeyboardInterrupt:
        return None
    finally:
        signal.signal(signal.SIGTERM, previous)
    return done.get("s", 0.0)


def main(argv: list[str]) -> int:
    """Run the node until SIGINT/SIGTERM; returns the process exit code."""
    from rclpy.utilities import remove_ros_args

    own = remove_ros_args(["sepfm", *argv])[1:]
    parser = argparse.ArgumentParser(
        prog="sepfm_ros node",
        usage="%(prog)s [--ros-args -p NAME:=VALUE ... --params-file FILE -r FROM:=TO ...]",
        description=_usage(),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.parse_args(own)
    # before any image flows and before rclpy creates the DDS participant (see ros/memory.py)
    malloc_fixed = configure_malloc()
    dds_profiles = use_node_dds_profiles()
    limit_thread_pools(1)
    # compile (fresh install) or load the estimator's kernels before the first frame arrives
    warm_s = warm_up_interruptibly()
    if warm_s is None:
        print("sepfm_ros node: interrupted while preparing the estimator", flush=True)
        os._exit(0)  # the compiling thread cannot be joined; nothing is open yet
    rclpy.init(args=["sepfm", *argv])
    node = None
    try:
        try:
            node = SepfmNode()
        except ValueError as err:
            print(f"sepfm_ros node: {err}", flush=True)
            return 2
        node.get_logger().info(f"estimator kernels ready in {warm_s:.1f} s")
        node.get_logger().info(
            f"memory: malloc thresholds {'fixed' if malloc_fixed else 'left (not glibc)'}, "
            + ("DDS subscriptions with DYNAMIC history" if dds_profiles else "DDS config left")
        )
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        try:
            executor.spin()
        except (KeyboardInterrupt, ExternalShutdownException):
            pass
    finally:
        if node is not None:
            node.shutdown()
            node.destroy_node()
        rclpy.try_shutdown()
    return 0
