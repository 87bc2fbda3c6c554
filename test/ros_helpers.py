"""Shared helpers of the live-node tests: the node as a subprocess, a test-side rclpy client,
stamp listeners and image messages. Used by the live-node, replay and robustness tests.

Import this module only after ``pytest.importorskip("rclpy")``.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import rclpy
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterType, ParameterValue
from rcl_interfaces.srv import GetParameters, SetParameters
from rclpy.executors import MultiThreadedExecutor, SingleThreadedExecutor
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import Image
from std_msgs.msg import Header

from sepfm_msgs.msg import MatchArray, TwoViewEstimate
from sepfm_ros.ros.bags.results import match_table
from sepfm_ros.ros.msgs.diagnostics import status_values
from sepfm_ros.ros.msgs.fundamental import fundamental_from_msg
from sepfm_ros.ros.msgs.headers import stamp_ns

REPO = Path(__file__).resolve().parent.parent
RELIABLE = QoSProfile(depth=20, reliability=ReliabilityPolicy.RELIABLE)
ANSWER_TIMEOUT = 60.0  # s; generous: the machine is shared and 2-core
SETTLE_TIMEOUT = 120.0  # s; a loaded 2-core machine can take seconds per pair
# s; a node loading (or, after a source change, compiling) its kernels on a loaded machine
STARTUP_TIMEOUT = 120.0


# --------------------------------------------------------------------------- node subprocess


def call_service(client, request, timeout: float = 60.0, attempt: float = 5.0, answered=None):
    """``client``'s response to ``request``, sent again every ``attempt`` s until ``timeout`` s.

    Only for requests that are safe to send twice. DDS can lose a request made just after the
    server was discovered (``wait_for_service`` sees the server before both of the service's
    reader/writer pairs have matched; ros2/rmw_fastrtps#390, ros2/rmw_cyclonedds#187), and then
    the future never completes. Before each resend, ``answered()`` (when given) may return a
    stand-in for a response whose request was carried out but whose answer was lost (a lifecycle
    transition that took place), or None to send again.
    """
    assert client.wait_for_service(timeout_sec=STARTUP_TIMEOUT), f"{client.srv_name} never came"
    deadline = time.monotonic() + timeout
    while True:
        future = client.call_async(request)
        retry_at = min(time.monotonic() + attempt, deadline)
        while not future.done() and time.monotonic() < retry_at:
            time.sleep(0.01)
        if future.done():
            return future.result()
        client.remove_pending_request(future)
        assert time.monotonic() < deadline, f"{client.srv_name} did not answer in {timeout} s"
        if answered is not None and (stand_in := answered()) is not None:
            return stand_in


class NodeProcess:
    """``python -m sepfm_ros node --ros-args ...`` (or another ``command``) as a subprocess
    with its output in a file."""

    def __init__(
        self,
        name: str,
        tmp: Path,
        *ros_args: str,
        env: dict[str, str | None] | None = None,
        command: str = "node",
    ) -> None:
        """``env``: variables to set in the node's environment (None: unset it)."""
        self.name = name
        self.log_path = tmp / f"{name}.log"
        self._log = open(self.log_path, "w")  # noqa: SIM115 - closed in stop()
        cmd = [sys.executable, "-m", "sepfm_ros", command, "--ros-args", "-r", f"__node:={name}"]
        cmd += list(ros_args)
        environ = dict(os.environ, PYTHONUNBUFFERED="1", RCUTILS_LOGGING_BUFFERED_STREAM="0")
        for key, value in (env or {}).items():
            if value is None:
                environ.pop(key, None)
            else:
                environ[key] = value
        self.proc = subprocess.Popen(
            cmd, cwd=REPO, env=environ, stdout=self._log, stderr=subprocess.STDOUT
        )

    def output(self) -> str:
        if not self._log.closed:
            self._log.flush()
        return self.log_path.read_text()

    def stop(self, sig: int = signal.SIGINT, timeout: float = 15.0) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
                self._log.close()
                raise AssertionError(f"{self.name} did not stop within {timeout} s") from None
        self._log.close()
        return self.proc.returncode


# --------------------------------------------------------------------------- test-side client
class Client:
    """Publishes inputs to one node and collects its outputs, keyed by output stamp (ns)."""

    def __init__(
        self,
        ros,
        node_name: str,
        inputs: dict[str, tuple[str, type]],
        input_qos: QoSProfile = RELIABLE,
    ) -> None:
        self.ros = ros
        self.node_name = node_name
        self.lock = threading.Lock()
        self.matches: dict[int, MatchArray] = {}
        self.info: dict[int, TwoViewEstimate] = {}  # ~/estimate by output stamp
        self.debug: dict[int, Image] = {}
        self.health: list[dict[str, str]] = []
        self.info_time: dict[int, float] = {}  # output stamp -> time.monotonic() of receipt
        self.health_log: list[tuple[float, int, str]] = []  # (receipt time, level, message)
        self.pubs = {
            key: ros.node.create_publisher(msg_type, topic, input_qos)
            for key, (topic, msg_type) in inputs.items()
        }
        prefix = f"/{node_name}"
        self.subs = [
            ros.node.create_subscription(
                MatchArray, f"{prefix}/matches", self._keep(self.matches), RELIABLE
            ),
            ros.node.create_subscription(
                TwoViewEstimate, f"{prefix}/estimate", self._on_estimate, RELIABLE
            ),
            ros.node.create_subscription(
                DiagnosticArray, "/diagnostics", self._on_diagnostics, RELIABLE
            ),
        ]
        self._set = ros.node.create_client(SetParameters, f"{prefix}/set_parameters")
        self._get = ros.node.create_client(GetParameters, f"{prefix}/get_parameters")

    def _keep(self, store):
        def callback(msg):
            with self.lock:
                store[stamp_ns(msg.header.stamp)] = msg

        return callback

    def _on_estimate(self, msg):
        with self.lock:
            self.info[stamp_ns(msg.header.stamp)] = msg
            self.info_time[stamp_ns(msg.header.stamp)] = time.monotonic()

    def _on_diagnostics(self, msg):
        with self.lock:
            for status in msg.status:
                if status.name == f"/{self.node_name}: node":
                    self.health.append(status_values(status))
                    level = int.from_bytes(status.level, "little")
                    self.health_log.append((time.monotonic(), level, status.message))

    def subscribe_debug(self):
        """Subscribe to ~/debug_image (the node draws it only while subscribed): call
        :meth:`unsubscribe_debug` when done, so later tests see an undrawn node."""
        self._debug_sub = self.ros.node.create_subscription(
            Image, f"/{self.node_name}/debug_image", self._keep(self.debug), RELIABLE
        )

    def unsubscribe_debug(self):
        self.ros.node.destroy_subscription(self._debug_sub)
        self._debug_sub = None

    def wait_connected(self, timeout: float = STARTUP_TIMEOUT) -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            inputs = all(p.get_subscription_count() > 0 for p in self.pubs.values())
            outputs = self.ros.node.count_publishers(f"/{self.node_name}/estimate") > 0
            if inputs and outputs and self._set.service_is_ready() and self._node_side_matched():
                return
            time.sleep(0.05)
        raise AssertionError(f"node {self.node_name} not connected within {timeout} s")

    def _node_side_matched(self) -> bool:
        """Matching is one-sided: the node's own /diagnostics must also report its inputs
        matched to publishers and its results to subscribers, or the first pair can be lost."""
        with self.lock:
            last = self.health[-1] if self.health else {}
        return (
            int(last.get("input_publishers", 0)) >= 1
            and int(last.get("output_subscribers", 0)) >= 1
        )

    def publish(self, key: str, msg) -> None:
        self.pubs[key].publish(msg)

    def wait_info(self, stamp: int, timeout: float = ANSWER_TIMEOUT) -> TwoViewEstimate:
        """The node's ~/estimate for the output stamp (ns)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            with self.lock:
                if stamp in self.info:
                    return self.info[stamp]
            time.sleep(0.01)
        raise AssertionError(f"no ~/estimate for stamp {stamp} within {timeout} s")

    def wait_outputs(self, stamp: int, need_f: bool = True, timeout: float = ANSWER_TIMEOUT):
        """(TwoViewEstimate, F (3, 3) or None, match table) for the output stamp; the match
        table is :func:`~sepfm_ros.ros.bags.results.match_table` of ~/matches. ``need_f``: an
        answer without F fails the test with its status."""
        estimate = self.wait_info(stamp, timeout)
        if need_f and not estimate.has_f:
            raise AssertionError(f"no F for stamp {stamp}: {estimate.status_text}")
        deadline = time.monotonic() + 5.0
        while time.monotonic() < deadline:
            with self.lock:
                if stamp in self.matches:
                    F = fundamental_from_msg(estimate) if estimate.has_f else None
                    return estimate, F, match_table(self.matches[stamp])
            time.sleep(0.01)
        raise AssertionError(f"~/matches for stamp {stamp} missing ({estimate.status_text})")

    def latest_health(self, after: float, timeout: float = 10.0) -> dict[str, str]:
        """A /diagnostics report of this node received at least ``after`` s from now."""
        with self.lock:
            start = len(self.health)
        time.sleep(after)
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            with self.lock:
                if len(self.health) > start:
                    return self.health[-1]
            time.sleep(0.05)
        raise AssertionError(f"no /diagnostics report from {self.node_name}")

    def wait_settled(
        self, before: dict[str, str], stamps: list[int], timeout: float = SETTLE_TIMEOUT
    ) -> tuple[list[int], int, int]:
        """Wait until every pair the node formed since its /diagnostics report ``before`` is
        answered here (one of ``stamps``) or was dropped by the node (a newer pair replaced it;
        counted). Returns (the ``stamps`` answered, pairs formed, pairs dropped) since
        ``before``: how many are dropped depends on the machine's load, so a test checks the
        answers that came and that no pair went unaccounted, not how many came in time.

        Call it after the last input was sent; a reliable input's newest pair is always
        answered, so wait for its answer first (``wait_info``), or the report may come before
        the last inputs reached the node. Fails after ``timeout`` s.
        """
        deadline = time.monotonic() + timeout
        last_formed = None
        while True:
            report = self.latest_health(after=0.0, timeout=timeout)
            formed, dropped = (
                int(report[key]) - int(before[key])
                for key in ("synchronized_pairs", "dropped_pairs")
            )
            with self.lock:
                answered = [s for s in stamps if s in self.info]
            # settled, and no pair formed since the report before (inputs still arriving)
            if len(answered) + dropped >= formed and formed == last_formed:
                return answered, formed, dropped
            last_formed = formed
            if time.monotonic() > deadline:
                raise AssertionError(
                    f"{formed} pairs formed, {len(answered)} answered, {dropped} dropped"
                )

    def set_parameter(self, name: str, value) -> tuple[bool, str]:
        if isinstance(value, bool):
            pv = ParameterValue(type=ParameterType.PARAMETER_BOOL, bool_value=value)
        elif isinstance(value, int):
            pv = ParameterValue(type=ParameterType.PARAMETER_INTEGER, integer_value=value)
        elif isinstance(value, float):
            pv = ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=value)
        else:
            pv = ParameterValue(type=ParameterType.PARAMETER_STRING, string_value=value)
        request = SetParameters.Request(parameters=[ParameterMsg(name=name, value=pv)])
        result = call_service(self._set, request, timeout=30.0).results[0]
        return result.successful, result.reason

    def get_parameter(self, name: str):
        value = call_service(self._get, GetParameters.Request(names=[name])).values[0]
        return {
            ParameterType.PARAMETER_INTEGER: value.integer_value,
            ParameterType.PARAMETER_DOUBLE: value.double_value,
            ParameterType.PARAMETER_STRING: value.string_value,
        }[value.type]


class Ros:
    """An rclpy context of its own, its node and a background executor: the test process's
    (default), or a stand-in node's (``threads`` > 1: a multi-threaded executor)."""

    def __init__(self, name: str = "sepfm_live_test", threads: int = 1) -> None:
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = (
            SingleThreadedExecutor(context=self.context)
            if threads == 1
            else MultiThreadedExecutor(num_threads=threads, context=self.context)
        )
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self) -> None:
        try:
            self.executor.spin()
        except Exception:  # noqa: BLE001 - context shut down at teardown
            pass

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)
        self.thread.join(5.0)


class StampListener:
    """A test node of its own recording the header stamps (ns) of ``topics`` (name -> message
    type) as they arrive, and /clock's times with ``clock``, spun in a thread until
    :meth:`close`."""

    def __init__(self, topics: dict[str, type], clock: bool = False) -> None:
        self.ros = Ros()
        self.stamps: dict[str, list[int]] = {t: [] for t in topics}
        self.clock: list[int] = []
        for topic, cls in topics.items():
            got = self.stamps[topic]
            self.ros.node.create_subscription(
                cls, topic, lambda m, got=got: got.append(stamp_ns(m.header.stamp)), 10
            )
        if clock:
            self.ros.node.create_subscription(
                Clock, "/clock", lambda m: self.clock.append(stamp_ns(m.clock)), 10
            )

    def close(self) -> None:
        self.ros.close()


# --------------------------------------------------------------------------- messages
_clock = [int(time.time()) * 1_000_000_000]


def next_stamp(step_ms: int = 100) -> int:
    _clock[0] += step_ms * 1_000_000
    return _clock[0]


def header(stamp: int, frame_id: str = "cam") -> Header:
    return Header(
        stamp=Time(sec=stamp // 1_000_000_000, nanosec=stamp % 1_000_000_000), frame_id=frame_id
    )


def gray_to_bytes(gray: np.ndarray, encoding: str) -> tuple[np.ndarray, bool]:
    """(H, row_bytes) uint8 rows of ``gray`` in ``encoding``, and whether they are big-endian."""
    h, w = gray.shape
    if encoding in ("mono8", "8UC1"):
        return gray, False
    if encoding in ("mono16", "16UC1"):
        return (gray.astype(">u2") << 4).view(np.uint8).reshape(h, 2 * w), True
    if encoding in ("bgr8", "rgb8", "8UC3"):
        return np.repeat(gray, 3, axis=1), False
    if encoding in ("bgra8", "rgba8", "8UC4"):
        rgba = np.dstack([gray, gray, gray, np.full_like(gray, 255)])
        return rgba.reshape(h, 4 * w), False
    if encoding.startswith("bayer_"):
        return gray, False  # a grey scene looks the same through every colour filter
    if encoding in ("yuv422", "uyvy", "yuv422_yuy2", "yuyv"):
        out = np.full((h, w, 2), 128, np.uint8)
        out[..., 1 if encoding in ("yuv422", "uyvy") else 0] = gray
        return out.reshape(h, 2 * w), False
    raise ValueError(encoding)


def image_msg(gray: np.ndarray, stamp: int, encoding: str = "mono8", pad: int = 0) -> Image:
    rows, big = gray_to_bytes(gray, encoding)
    padded = np.concatenate([rows, np.zeros((rows.shape[0], pad), np.uint8)], axis=1)
    return Image(
        header=header(stamp),
        height=gray.shape[0],
        width=gray.shape[1],
        encoding=encoding,
        is_bigendian=int(big),
        step=padded.shape[1],
        data=padded.tobytes(),
    )


def start_node(name, tmp, ros, inputs, *args, input_qos: QoSProfile = RELIABLE, env=None):
    """Start a node subprocess (``env``: see :class:`NodeProcess`) and a connected
    :class:`Client` for it."""
    proc = NodeProcess(name, tmp, *args, env=env)
    client = Client(ros, name, inputs, input_qos)
    try:
        client.wait_connected()
    except AssertionError:
        proc.stop()
        raise AssertionError(f"{name} did not come up:\n{proc.output()}") from None
    return proc, client


def send_pair(client, left: Image, right: Image, right_first: bool = False) -> None:
    order = (
        [("right", right), ("left", left)] if right_first else [("left", left), ("right", right)]
    )
    for key, msg in order:
        client.publish(key, msg)


def rss_mb(pid: int) -> float:
    """Resident set size of process ``pid`` in MB (from /proc)."""
    text = Path(f"/proc/{pid}/status").read_text()
    return int(re.search(r"VmRSS:\s+(\d+) kB", text).group(1)) / 1024.0
