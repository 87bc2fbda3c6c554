"""``sepfm_ros demo``: the main job on a bag the package ships, through the live node.

Starts the ``sepfm`` node as a subprocess, replays a bundled bag (``bags/synthetic_stereo`` by
default: a rendered scene with exact ground truth) into it over DDS at the recorded rate (and
reliable, whatever QoS the bag recorded: large best-effort frames are lost on this host), each
pair's frames held back until the node has answered the pair before (a node that falls behind
passes over stale pairs, by design; the demo shows a row for every pair, so on a busy machine it
replays slower than recorded), records the node's outputs into a bag, then prints a per-frame
table (stamp, matches, inliers, hypotheses, error against ground truth) and writes the node's
debug image of one frame as a PNG. All of it stays on this machine: a random ``ROS_DOMAIN_ID``
and localhost-only discovery unless set.

    sepfm_ros demo [--bag BAG] [--out DIR] [--rate R] [-p NAME:=VALUE ...]
"""

from __future__ import annotations

import argparse
import bisect
import os
import random
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO, TYPE_CHECKING

import cv2
import numpy as np

from sepfm_ros.ros.bags.errors import BagError
from sepfm_ros.ros.bags.reader import BagReader, RawMessage
from sepfm_ros.ros.bags.writer import check_output_path

if TYPE_CHECKING:
    from rclpy.context import Context
    from rclpy.node import Node

    from sepfm_ros.ros.bags.inputs import InputSpec
    from sepfm_ros.ros.node.recorder import Recorder
    from sepfm_ros.ros.node.replayer import Replayer

PACKAGE_DIR = Path(__file__).resolve().parent
DEFAULT_BAG = "synthetic_stereo"


def bundled_bags_dir() -> Path:
    """The folder of the bags the package ships.

    ``bags/`` beside the package in a source tree / editable install, or
    ``<prefix>/share/sepfm_ros/bags`` after ``pip install`` or ``colcon build``.
    """
    candidates = [PACKAGE_DIR.parent / "bags", Path(sys.prefix) / "share" / "sepfm_ros" / "bags"]
    try:
        from ament_index_python.packages import get_package_share_directory

        candidates.append(Path(get_package_share_directory("sepfm_ros")) / "bags")
    except Exception:  # noqa: BLE001 - ament_index is optional (not in a plain venv)
        pass
    for c in candidates:
        if (c / DEFAULT_BAG / "metadata.yaml").is_file():
            return c
    raise BagError(
        "the bundled bags were not found (looked in "
        + ", ".join(str(c) for c in candidates)
        + "); rebuild them with: python scripts/make_bundled_bags.py"
    )


def isolate_ros_environment() -> None:
    """Pick a random ROS_DOMAIN_ID and localhost-only discovery unless the user set them."""
    if "ROS_DOMAIN_ID" not in os.environ:
        os.environ["ROS_DOMAIN_ID"] = str(random.SystemRandom().randint(1, 200))
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")


@dataclass
class LiveRun:
    """What :func:`replay_through_node` did."""

    expected_pairs: int
    published: int
    received: dict[str, int]
    node_returncode: int | None
    output: Path


def replay_through_node(
    bag: Path,
    out: Path,
    params: list[str] | None = None,
    rate: float = 1.0,
    debug_image: bool = True,
    progress: bool = True,
    log_path: Path | None = None,
    startup_timeout_s: float = 120.0,
    answer_timeout_s: float = 120.0,
) -> LiveRun:
    """Replay ``bag`` into a fresh ``sepfm`` node subprocess and record its outputs to ``out``.

    ``params`` are extra node parameters (``name:=value``); mode and transport follow the bag.
    The ROS environment (ROS_DOMAIN_ID) of this process is used for the node too. The node
    runs at its default settings: its subscriptions take the player's (recorded) reliability.
    Paced by answers: a message is published at its recorded time (scaled by ``rate``) or, when
    later, once the node answered every pair completed before it, so every pair is answered
    however busy the machine; a pair still unanswered after ``answer_timeout_s`` seconds
    without any new answer is given up (it lacks a row).
    """
    from sepfm_ros.ros.bags.inputs import camera_info_topics
    from sepfm_ros.ros.bags.results import output_topics
    from sepfm_ros.ros.node.replayer import Replayer

    params = list(params or [])
    check_output_path(out)
    spec, completions = _pair_completions(bag, params)
    expected = len(completions)
    node_proc, log = _start_node(spec, params, log_path)
    listener = _start_listener(out, debug_image)
    counts = listener.recorder.counts
    answers = Answers(counts, list(output_topics().values()), node_proc, answer_timeout_s)

    def hold(msg: RawMessage) -> None:
        """Before ``msg``: the node's answers to every pair completed before it."""
        answers.wait(bisect.bisect_left(completions, msg.log_time_ns))

    replayer = None
    published = 0
    try:
        # the images and, where the bag has them, their camera_info (calibrated outputs)
        with BagReader(bag) as reader:
            infos = [t for t in camera_info_topics(reader, spec) if t in reader.topics]
        # reliable whatever the bag recorded: a best-effort camera's recording would otherwise
        # lose its large frames to the transport on this host (sepfm_ros/ros/dds.py)
        replayer = Replayer(
            listener.node, bag, topics=[*spec.topics, *infos], rate=rate, reliable=True
        )
        _wait_until_serving(node_proc, listener, replayer, spec, bag, infos, startup_timeout_s)
        time.sleep(0.2)
        published = replayer.run(progress=progress, hold=hold)
        answers.wait(expected)
        time.sleep(0.3)  # let the debug image of the final pair arrive (drawn after the answer)
    finally:
        _stop_node(node_proc)
        listener.stop_spinning()
        if replayer is not None:
            replayer.close()
        listener.close()
        if log is not subprocess.DEVNULL:
            log.close()
    return LiveRun(expected, published, dict(counts), node_proc.returncode, out)


def _pair_completions(bag: Path, params: list[str]) -> tuple[InputSpec, list[int]]:
    """The bag's inputs, and the log time (ns) of the message completing each pair the node
    forms with ``params`` (its pairing), in bag order."""
    from sepfm_ros.ros.bags.inputs import detect_inputs
    from sepfm_ros.ros.bags.pairing import iter_pairs
    from sepfm_ros.ros.session.parameters import parse_params
    from sepfm_ros.ros.session.session import Session

    with BagReader(bag) as reader:
        spec = detect_inputs(reader)
        session = Session(parse_params(params), spec.mode == "stereo", spec.topics)
        completions = [job.log_time_ns for job in iter_pairs(reader, spec, session)]
    return spec, completions


def _start_node(
    spec: InputSpec, params: Sequence[str], log_path: Path | None
) -> tuple[subprocess.Popen, IO[str] | int]:
    """Start the ``sepfm`` node subprocess for the bag's inputs with ``params``, its output to
    ``log_path`` (or discarded); the process and the open log (or ``subprocess.DEVNULL``)."""
    cmd = [sys.executable, "-m", "sepfm_ros", "node", "--ros-args", *spec.node_params()]
    for p in params:
        cmd += ["-p", p]
    log = open(log_path, "w") if log_path else subprocess.DEVNULL  # noqa: SIM115
    node_proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=dict(os.environ))
    return node_proc, log


@dataclass
class _Listener:
    """The demo's own ROS node, spun on a thread of its own: it records the sepfm node's outputs
    and reads the node's /diagnostics.

    Attributes:
        matched: the node's own counts from /diagnostics: matched input publishers
            (``input_publishers``), result subscribers (``output_subscribers``) and
            ``camera_info_ready`` (1 once every camera's camera_info arrived).
    """

    context: Context
    node: Node
    recorder: Recorder
    matched: dict[str, int]
    stop: threading.Event
    spinner: threading.Thread

    def stop_spinning(self) -> None:
        """Stop the spinning thread (waits up to 5 s)."""
        self.stop.set()
        self.spinner.join(timeout=5)

    def close(self) -> None:
        """Close the recording, destroy the node and shut its ROS context down."""
        import rclpy

        self.recorder.close()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


def _start_listener(out: Path, debug_image: bool) -> _Listener:
    """A fresh ROS context and node recording the sepfm node's outputs (and its debug image with
    ``debug_image``) into the bag ``out``, listening to /diagnostics, spinning on a thread."""
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import SingleThreadedExecutor

    from sepfm_ros.ros.bags.results import calibrated_topics, output_topics
    from sepfm_ros.ros.bags.writer import BagWriter
    from sepfm_ros.ros.node.recorder import Recorder

    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node(f"sepfm_demo_{os.getpid()}", context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    topics = list(output_topics().values()) + list(calibrated_topics().values())
    if debug_image:
        topics.append("/sepfm/debug_image")
    writer = BagWriter(out, flush_interval_s=1.0)
    recorder = Recorder(node, writer, topics)
    # the node's own counts of matched input publishers and output subscribers (/diagnostics)
    node_matched = {"input_publishers": 0, "output_subscribers": 0, "camera_info_ready": 0}

    def on_diagnostics(msg: DiagnosticArray) -> None:
        for status in msg.status:
            for kv in status.values:
                if kv.key in node_matched and kv.value.isdigit():
                    node_matched[kv.key] = int(kv.value)

    node.create_subscription(DiagnosticArray, "/diagnostics", on_diagnostics, 10)
    stop = threading.Event()

    def spin() -> None:
        while not stop.is_set():
            executor.spin_once(timeout_sec=0.05)

    spinner = threading.Thread(target=spin, daemon=True)
    spinner.start()
    return _Listener(context, node, recorder, node_matched, stop, spinner)


def _wait_until_serving(
    node_proc: subprocess.Popen,
    listener: _Listener,
    replayer: Replayer,
    spec: InputSpec,
    bag: Path,
    infos: Sequence[str],
    startup_timeout_s: float,
) -> None:
    """Wait (at most ``startup_timeout_s`` s in all) until the node's outputs are up, it and the
    player and recorder have matched, and it holds the camera_info of ``infos`` (the first of
    each published here first); BagError when the node exits or time runs out."""
    deadline = time.monotonic() + startup_timeout_s
    while not listener.recorder.ready():
        if node_proc.poll() is not None:
            raise BagError(f"the node exited with code {node_proc.returncode} at start-up")
        if time.monotonic() > deadline:
            raise BagError(f"the node's outputs did not appear within {startup_timeout_s} s")
        time.sleep(0.05)
    replayer.wait_for_subscribers(spec.topics, max(1.0, deadline - time.monotonic()))
    # matching is one-sided: also wait until the node's inputs have matched our publishers
    # and its result publishers our recorder (its /diagnostics reports both), or the first
    # messages can be lost
    matched = listener.matched
    _wait_until(
        lambda: matched["input_publishers"] >= 1 and matched["output_subscribers"] >= 1,
        deadline,
        "the node did not match the player and recorder within the timeout",
    )
    if infos:
        # a camera driver publishes camera_info all along: the node has it before the first
        # pair, as `process` has (the bag may hold a frame's image before its camera_info)
        prime_camera_info(replayer, bag, infos)
        _wait_until(
            lambda: matched["camera_info_ready"] >= 1,
            deadline,
            "the node did not receive camera_info within the timeout",
        )


def _wait_until(done: Callable[[], bool], deadline: float, error: str) -> None:
    """Poll ``done`` every 50 ms until it holds; BagError(``error``) once ``deadline``
    (``time.monotonic()`` s) has passed."""
    while not done():
        if time.monotonic() > deadline:
            raise BagError(error)
        time.sleep(0.05)


def _stop_node(node_proc: subprocess.Popen) -> None:
    """Stop the node subprocess if it runs: SIGINT, then kill after 15 s."""
    if node_proc.poll() is None:
        node_proc.send_signal(signal.SIGINT)
        try:
            node_proc.wait(timeout=15)
        except subprocess.TimeoutExpired:
            node_proc.kill()
            node_proc.wait()


def prime_camera_info(replayer: Replayer, bag: Path, topics: Sequence[str]) -> None:
    """Publish the first camera_info message of each of ``topics`` from ``bag`` through the
    replayer's publishers (before the replay itself)."""
    first: dict[str, bytes] = {}
    with BagReader(bag) as reader:
        for msg in reader.messages(list(topics)):
            first.setdefault(msg.topic, msg.data)
            if len(first) == len(topics):
                break
    for topic, data in first.items():
        replayer.publishers[topic].publish(data)


class Answers:
    """The node's answers as the recorder counts them: wait for a number of them.

    Args:
        counts: the recorder's messages per topic (updated by the spinning thread).
        topics: the topics each answer has one message on (the estimate and the matches).
        node_proc: the node subprocess (waiting ends when it exits).
        timeout_s: a wait gives up after this many seconds without a new answer; the pairs then
            missing are not waited for again.
    """

    def __init__(
        self,
        counts: Mapping[str, int],
        topics: Sequence[str],
        node_proc: subprocess.Popen,
        timeout_s: float,
    ) -> None:
        self._counts = counts
        self._topics = list(topics)
        self._node = node_proc
        self._timeout_s = timeout_s
        self._given_up = 0  # pairs never answered (waits that timed out)

    def answered(self) -> int:
        """Pairs whose estimate and matches both arrived."""
        return min(self._counts[t] for t in self._topics)

    def wait(self, pairs: int) -> None:
        """Block until ``pairs`` pairs (less those given up before) are answered, the node has
        exited, or ``timeout_s`` passed without a new answer."""
        last, seen = time.monotonic(), self.answered()
        while (done := self.answered()) < pairs - self._given_up and self._node.poll() is None:
            if done != seen:
                last, seen = time.monotonic(), done
            elif time.monotonic() - last > self._timeout_s:
                self._given_up = pairs - done
                return
            time.sleep(0.02)


def write_debug_image(live_bag: Path, stamp_ns: int, path: Path) -> bool:
    """Write the node's ~/debug_image at ``stamp_ns`` (or the nearest) as PNG; False if none."""
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import Image

    from sepfm_ros.ros.msgs.headers import stamp_ns as to_ns
    from sepfm_ros.ros.msgs.image_conversion import message_to_numpy

    best = None
    with BagReader(live_bag) as reader:
        if "/sepfm/debug_image" not in reader.topics:
            return False
        for raw in reader.messages(["/sepfm/debug_image"]):
            msg = deserialize_message(raw.data, Image)
            s = to_ns(msg.header.stamp)
            if best is None or abs(s - stamp_ns) < abs(best[0] - stamp_ns):
                best = (s, msg)
    if best is None:
        return False
    return bool(cv2.imwrite(str(path), message_to_numpy(best[1], "bgr8")))


def calibration_summary(live_bag: Path, results: list) -> str | None:
    """One line on the calibrated outputs (camera_info in the bag): the median relative pose
    of the answered pairs and the node's last calibration check; None without them."""
    from sepfm_msgs.msg import TwoViewEstimate
    from sepfm_ros.geometry.calibrated.calibration_check import LEVEL_NAMES
    from sepfm_ros.ros.bags.results import read_calibration_checks

    poses = [
        r.estimate
        for r in results
        if r.estimate is not None and r.estimate.pose_kind != TwoViewEstimate.POSE_NONE
    ]
    if not poses:
        return None
    rotation = float(np.median([p.rotation_deg for p in poses]))
    translations = [
        [p.pose.translation.x, p.pose.translation.y, p.pose.translation.z] for p in poses
    ]
    directions = [np.asarray(t) / np.linalg.norm(t) for t in translations]
    direction = np.median(directions, axis=0)
    line = (
        f"relative pose (camera_info): {len(poses)} pairs, median rotation {rotation:.2f} deg,"
        f" translation direction {np.round(direction, 3).tolist()}"
    )
    if poses[-1].pose_kind == TwoViewEstimate.POSE_METRIC:
        line += f", baseline {float(np.linalg.norm(translations[-1])):.3f} m"
    checks = read_calibration_checks(live_bag)
    if checks:
        last = checks[-1].status
        line += f"; calibration check {LEVEL_NAMES[last.level[0]]}: {last.message}"
    return line


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(
        prog="sepfm_ros demo",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--bag", type=Path, help=f"bag to replay (default: bundled {DEFAULT_BAG})")
    parser.add_argument("--out", type=Path, help="output folder (default results/demo-<time>)")
    parser.add_argument("--rate", type=float, default=1.0, help="replay speed (default 1)")
    parser.add_argument("-p", "--param", action="append", default=[], metavar="NAME:=VALUE")
    parser.add_argument("--quiet", action="store_true", help="no progress line")
    parser.add_argument(
        "--picture", type=Path, help="also write the debug image here (README's docs/demo.png)"
    )
    args = parser.parse_args(argv)
    try:
        bag = args.bag or bundled_bags_dir() / DEFAULT_BAG
        out = args.out or Path("results") / time.strftime("demo-%Y%m%d-%H%M%S")
        check_output_path(out)
        out.mkdir(parents=True)
        isolate_ros_environment()
        # the node loads the estimator's compiled kernels from the on-disk cache; on the first
        # run after an install they are compiled here once (tens of seconds), with a message
        print("preparing the estimator (compiled once after an install) ...", end=" ", flush=True)
        from sepfm_ros.pipeline.compiled import warm_up

        print(f"{warm_up():.1f} s")
        print(
            f"replaying {bag} through the live sepfm node"
            f" (ROS_DOMAIN_ID={os.environ['ROS_DOMAIN_ID']})"
        )
        run = replay_through_node(
            bag,
            out / "live",
            args.param,
            args.rate,
            progress=not args.quiet,
            log_path=out / "node.log",
        )
        from sepfm_ros.ros.bags.results import format_summary, format_table, read_results, summarize

        results = read_results(run.output, gt_bag=bag)
    except BagError as err:
        print(f"sepfm_ros demo: error: {err}", file=sys.stderr)
        return 1
    print(format_table(results))
    print(format_summary(summarize(results, run.expected_pairs)))
    calibrated = calibration_summary(run.output, results)
    if calibrated:
        print(calibrated)
    if results:
        ranked = sorted(results, key=lambda r: r.inliers)
        pick = ranked[len(ranked) // 2]
        png = out / "debug.png"
        if write_debug_image(run.output, pick.stamp_ns, png):
            print(f"debug image (inliers, line pair, epipolar lines): {png}")
            if args.picture is not None:
                args.picture.write_bytes(png.read_bytes())
    print(f"outputs recorded in {run.output}; node log {out / 'node.log'}")
    return 0 if results else 1
