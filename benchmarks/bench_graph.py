"""Benchmark: the sepfm node in the ROS graph: start-up to graph visibility, CPU while idle
(no subscriber of its answers) against answering, and the time from the first subscriber to the
first answer.

A camera in this process publishes VGA colour images (640x480 bgr8, reliable) at 30 Hz on
``/bench/image_raw``; the node (``python -m sepfm_ros node``, motion mode, on demand) runs as a
subprocess on a ROS domain of its own.

- start-up to graph visibility: from launching the process to the first answer of its
  ``~/get_state`` service (lifecycle_msgs), cold (an empty numba cache: the kernels compile)
  and warm (the kernels cached by ``sepfm_ros warm_up`` just before); beside it, the time
  until the node is active (kernels ready, configured and activated by ``autostart``);
- idle CPU: the node process's CPU time (user + system, /proc) over a window while the camera
  publishes and nothing subscribes to its outputs, in % of one core; the same with a
  subscriber of ``~/estimate`` (the node answering every pair it can);
- first answer: from creating a subscription of ``~/estimate`` to receiving the first
  estimate, over a few rounds (the subscriber leaves and the node goes idle between rounds).

    python benchmarks/bench_graph.py [--write-docs] [--window 20] [--rounds 5]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import rclpy
from lifecycle_msgs.msg import State
from lifecycle_msgs.srv import GetState
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_docs  # noqa: E402

from sepfm_msgs.msg import TwoViewEstimate  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
RELIABLE = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
TOPIC = "/bench/image_raw"
NAME = "bench_graph"
RATE_HZ = 30.0
TARGET_IDLE_PERCENT = 2.0


class Graph:
    """This process's rclpy node on its own executor thread, a 30 Hz VGA colour camera and the
    clients of the node under test."""

    def __init__(self) -> None:
        rclpy.init()
        self.node = rclpy.create_node("bench_graph_client")
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.node)
        threading.Thread(target=self.executor.spin, daemon=True).start()
        self.camera = self.node.create_publisher(Image, TOPIC, RELIABLE)
        rng = np.random.default_rng(0)
        self.frames = [(rng.random((480, 640, 3)) * 255).astype(np.uint8) for _ in range(4)]
        self._stop = threading.Event()
        threading.Thread(target=self._publish, daemon=True).start()
        self.get_state = self.node.create_client(GetState, f"/{NAME}/get_state")
        self.answers: list[float] = []  # receipt times of ~/estimate

    def _publish(self) -> None:
        k = 0
        period = 1.0 / RATE_HZ
        next_t = time.monotonic()
        while not self._stop.is_set():
            frame = self.frames[k % len(self.frames)]
            msg = Image(height=480, width=640, encoding="bgr8", step=640 * 3, data=frame.tobytes())
            msg.header.stamp = self.node.get_clock().now().to_msg()
            msg.header.frame_id = "cam"
            self.camera.publish(msg)
            k += 1
            next_t += period
            time.sleep(max(next_t - time.monotonic(), 0.0))

    def state(self, timeout: float = 5.0) -> int | None:
        """The node's lifecycle state id, None when get_state does not answer."""
        if not self.get_state.service_is_ready():
            return None
        future = self.get_state.call_async(GetState.Request())
        deadline = time.monotonic() + timeout
        while not future.done() and time.monotonic() < deadline:
            time.sleep(0.005)
        return future.result().current_state.id if future.done() else None

    def subscribe(self):
        return self.node.create_subscription(
            TwoViewEstimate,
            f"/{NAME}/estimate",
            lambda m: self.answers.append(time.monotonic()),
            RELIABLE,
        )

    def close(self) -> None:
        self._stop.set()
        self.executor.shutdown()
        rclpy.try_shutdown()


def start_node(cache: str | None) -> subprocess.Popen:
    env = dict(os.environ)
    if cache is not None:
        env["NUMBA_CACHE_DIR"] = cache
    cmd = [sys.executable, "-m", "sepfm_ros", "node", "--ros-args", "-r", f"__node:={NAME}"]
    cmd += ["-p", "mode:=motion", "-r", f"image_raw:={TOPIC}"]
    return subprocess.Popen(
        cmd, cwd=REPO, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )


def stop_node(proc: subprocess.Popen) -> None:
    proc.send_signal(2)
    try:
        proc.wait(20)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def startup(graph: Graph, cache: str | None) -> tuple[float, float, subprocess.Popen]:
    """(s to the first get_state answer, s to active, the running node)."""
    t0 = time.monotonic()
    proc = start_node(cache)
    visible = None
    while True:
        state = graph.state()
        now = time.monotonic()
        if state is not None and visible is None:
            visible = now - t0
        if state == State.PRIMARY_STATE_ACTIVE:
            assert visible is not None
            return visible, now - t0, proc
        if now - t0 > 600:
            raise RuntimeError("the node did not become active in 600 s")
        time.sleep(0.02)


def cpu_percent(pid: int, window_s: float) -> float:
    """The process's CPU (user + system) over ``window_s``, % of one core."""

    def ticks() -> int:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        return int(fields[11]) + int(fields[12])

    hz = os.sysconf("SC_CLK_TCK")
    t0, c0 = time.monotonic(), ticks()
    time.sleep(window_s)
    return 100.0 * (ticks() - c0) / hz / (time.monotonic() - t0)


def wait_for(condition, timeout: float = 30.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise RuntimeError("timed out")
        time.sleep(0.01)


def first_answers(graph: Graph, rounds: int) -> list[float]:
    """Seconds from subscribing to ~/estimate to the first estimate, per round."""
    times = []
    for _ in range(rounds):
        wait_for(lambda: graph.node.count_subscribers(TOPIC) == 0)
        graph.answers.clear()
        t0 = time.monotonic()
        sub = graph.subscribe()
        wait_for(lambda: len(graph.answers) > 0, 60.0)
        times.append(graph.answers[0] - t0)
        graph.node.destroy_subscription(sub)
    return times


def run(window_s: float, rounds: int) -> str:
    graph = Graph()
    try:
        with tempfile.TemporaryDirectory() as cache:
            cold_visible, cold_active, proc = startup(graph, cache)
            stop_node(proc)
        # the package's own cache, compiled first (`sepfm_ros warm_up`): a warm start loads it
        subprocess.run(
            [sys.executable, "-m", "sepfm_ros", "warm_up"],
            cwd=REPO,
            check=True,
            stdout=subprocess.DEVNULL,
        )
        visible, active, proc = startup(graph, None)
        try:
            time.sleep(2.0)
            idle = cpu_percent(proc.pid, window_s)
            subscribed = graph.node.count_subscribers(TOPIC)
            sub = graph.subscribe()
            wait_for(lambda: len(graph.answers) > 0, 60.0)
            busy = cpu_percent(proc.pid, window_s)
            answered = len(graph.answers)
            graph.node.destroy_subscription(sub)
            firsts = first_answers(graph, rounds)
        finally:
            stop_node(proc)
    finally:
        graph.close()
    rows = [
        "| figure | value |",
        "|---|---|",
        f"| start-up to graph visibility (get_state answers), cold kernel cache | "
        f"{cold_visible:.2f} s (active after {cold_active:.1f} s) |",
        f"| start-up to graph visibility, warm kernel cache | {visible:.2f} s (active after "
        f"{active:.1f} s) |",
        f"| node CPU, no subscriber, camera at {RATE_HZ:.0f} Hz VGA colour | {idle:.2f} % of a "
        f"core (target < {TARGET_IDLE_PERCENT:g} %; image subscriptions held: {subscribed}) |",
        f"| node CPU, one ~/estimate subscriber | {busy:.0f} % of a core ({answered} answers in "
        f"{window_s:.0f} s) |",
        f"| first subscriber to first answer, {rounds} rounds | median "
        f"{statistics.median(firsts):.2f} s, max {max(firsts):.2f} s |",
    ]
    return (
        f"The node (motion mode, on demand) as a subprocess; a camera publishing 640x480 bgr8 at "
        f"{RATE_HZ:.0f} Hz (reliable) in the benchmark's process; CPU over {window_s:.0f} s "
        "windows from /proc.\n\n" + "\n".join(rows)
    )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--window", type=float, default=20.0, help="CPU window, s")
    ap.add_argument("--rounds", type=int, default=5, help="first-answer rounds")
    ap.add_argument("--doc", type=Path, default=bench_docs.BENCH_DOC)
    ap.add_argument("--write-docs", action="store_true", help="rewrite its docs section")
    args = ap.parse_args(argv)
    os.environ.setdefault("ROS_DOMAIN_ID", str(150 + os.getpid() % 60))
    text = run(args.window, args.rounds)
    print(text)
    if args.write_docs:
        command = bench_docs.command_line("bench_graph.py", argv)
        section = bench_docs.section(
            "bench_graph", "The node in the graph: start-up, idle CPU, first answer", command, text
        )
        path = bench_docs.write_section("bench_graph", section, args.doc)
        print(f"wrote {path}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
