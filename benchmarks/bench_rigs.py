"""Many stereo rigs on one host: one node per rig, as ``launch/sepfm_rigs_launch.py`` starts them.

    python benchmarks/bench_rigs.py [--rigs 1 2 3 4] [--seconds 10] [--rate 10] [--write-docs]

For each rig count N, N node processes are started exactly as the launch file starts them (node
``sepfm`` in namespace ``/rigK``, stereo mode, default parameters, inputs
``/rigK/left/image_raw`` and ``/rigK/right/image_raw``); this process publishes KITTI's mono8
stereo pairs (1241x376) to every rig at ``--rate`` Hz for ``--seconds`` after each node has
answered three pairs, and counts each rig's answers on ``/rigK/sepfm/estimate``. Printed per
N: the share of pairs answered (worst rig and all rigs), the nodes' latency p50/p95, each node's
CPU time per answered pair and the host's CPU used by the nodes. The publisher shares the
machine (its cost is part of what a robot's drivers cost).
"""

from __future__ import annotations

import argparse
import os
import random
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import bench_docs
import cv2
import numpy as np
from bench_node import cpu_seconds, pct

REPO = Path(__file__).resolve().parent.parent
DATA = REPO.parent / "shared" / "data"


class RigFeeder:
    """One rclpy node publishing every rig's stereo pairs and collecting their answers."""

    def __init__(self, rigs: list[str]) -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import Image

        from sepfm_msgs.msg import TwoViewEstimate

        self.rclpy = rclpy
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node("sepfm_bench_rigs", context=self.context)
        qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self.pubs = {
            rig: [
                self.node.create_publisher(Image, f"/{rig}/{side}/image_raw", qos)
                for side in ("left", "right")
            ]
            for rig in rigs
        }
        self.lock = threading.Lock()
        self.answers: dict[str, dict[int, float]] = {rig: {} for rig in rigs}
        for rig in rigs:
            self.node.create_subscription(
                TwoViewEstimate,
                f"/{rig}/sepfm/estimate",
                lambda msg, rig=rig: self._on_info(rig, msg),
                qos,
            )
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self) -> None:
        try:
            while not self.stop.is_set():
                self.executor.spin_once(timeout_sec=0.05)
        except Exception:  # noqa: BLE001 - shut down at exit
            pass

    def _on_info(self, rig: str, msg) -> None:
        stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
        latency = next((t.ms for t in msg.timings if t.stage == "latency"), float("nan"))
        with self.lock:
            self.answers[rig][stamp] = float(latency)

    def wait_connected(self, timeout: float = 300.0) -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if all(p.get_subscription_count() for ps in self.pubs.values() for p in ps):
                return
            time.sleep(0.1)
        raise RuntimeError("a rig's node did not subscribe")

    def send(self, rig: str, msgs, stamp: int) -> None:
        for pub, msg in zip(self.pubs[rig], msgs, strict=True):
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 10**9)
            pub.publish(msg)

    def answered(self, rig: str, stamps: list[int]) -> list[float]:
        with self.lock:
            return [self.answers[rig][s] for s in stamps if s in self.answers[rig]]

    def close(self) -> None:
        self.stop.set()
        self.thread.join(timeout=5.0)
        self.executor.shutdown()
        self.node.destroy_node()
        self.rclpy.try_shutdown(context=self.context)


def node_command(rig: str) -> list[str]:
    """The node of one rig, as launch/sepfm_rigs_launch.py starts it."""
    return [sys.executable, "-m", "sepfm_ros", "node", "--ros-args", "-r", f"__ns:=/{rig}",
            "-p", "mode:=stereo"]  # fmt: skip


def _pairs() -> list[tuple]:
    from sepfm_ros.ros.msgs.image_conversion import numpy_to_image

    out = []
    for k in range(10):
        images = [
            cv2.imread(str(DATA / f"kitti_seq2/{side}/{k:06d}.png"), cv2.IMREAD_GRAYSCALE)
            for side in ("left", "right")
        ]
        out.append(tuple(numpy_to_image(i, "mono8") for i in images))
    return out


def run_rigs(n: int, seconds: float, rate: float, env: dict) -> float:
    """Run ``n`` rigs and print their row; returns the nodes' mean CPU ms per answered pair."""
    rigs = [f"rig{k}" for k in range(n)]
    procs = [
        subprocess.Popen(
            node_command(rig),
            cwd=REPO,
            env=env,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.STDOUT,
        )  # fmt: skip
        for rig in rigs
    ]
    feeder = RigFeeder(rigs)
    try:
        feeder.wait_connected()
        pairs = _pairs()
        frame = 0
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:  # warm-up: three answers from every node
            stamp = time.time_ns()
            for rig in rigs:
                feeder.send(rig, pairs[frame % len(pairs)], stamp)
            frame += 1
            time.sleep(1.0 / rate)
            with feeder.lock:
                if all(len(a) >= 3 for a in feeder.answers.values()):
                    break
        cpu0 = [cpu_seconds(p.pid) for p in procs]
        sent: list[int] = []
        start = time.monotonic()
        k = 0
        while time.monotonic() - start < seconds:
            time.sleep(max(0.0, start + k / rate - time.monotonic()))
            stamp = time.time_ns()
            for rig in rigs:
                feeder.send(rig, pairs[frame % len(pairs)], stamp)
            frame += 1
            sent.append(stamp)
            k += 1
        elapsed = time.monotonic() - start
        cpu = [cpu_seconds(p.pid) - c for p, c in zip(procs, cpu0, strict=True)]
        time.sleep(2.0)  # the last answers
        got = [feeder.answered(rig, sent) for rig in rigs]
        shares = [len(g) / len(sent) for g in got]
        latency = [v for g in got for v in g]
        per_pair = [c * 1e3 / max(1, len(g)) for c, g in zip(cpu, got, strict=True)]
        print(
            f"| {n} | {100 * min(shares):.0f} % | {100 * sum(map(len, got)) / (n * len(sent)):.0f}"
            f" % | {pct(latency, 50):.0f} / {pct(latency, 95):.0f} | "
            f"{np.mean(per_pair):.0f} | {100 * sum(cpu) / elapsed:.0f} % | "
            f"{os.getloadavg()[0]:.1f} |",
            flush=True,
        )
        return float(np.mean(per_pair))
    finally:
        feeder.close()
        for p in procs:
            p.send_signal(signal.SIGINT)
        for p in procs:
            try:
                p.wait(15)
            except subprocess.TimeoutExpired:  # never leave a node running
                p.kill()
                p.wait()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rigs", type=int, nargs="+", default=[1, 2, 3, 4])
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--rate", type=float, default=10.0, help="pairs/s per rig")
    ap.add_argument("--write-docs", action="store_true")
    a = ap.parse_args(argv)
    if not DATA.is_dir():
        print(f"shared data not found at {DATA}", file=sys.stderr)
        return 2
    os.environ.setdefault("ROS_DOMAIN_ID", str(random.SystemRandom().randint(1, 200)))
    env = dict(os.environ)  # the nodes in the caller's environment, as bench_node runs them
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    with bench_docs.captured_stdout() as out:
        print(
            f"One node per rig (launch/sepfm_rigs_launch.py's), KITTI mono8 stereo 1241x376 at "
            f"{a.rate:g} Hz per rig for {a.seconds:g} s, default parameters (sep4, ORB 1000); "
            f"{os.cpu_count()} CPUs shared with the publisher and with other work.\n"
        )
        print(
            "| rigs | answered, worst rig | answered, all rigs | latency p50 / p95 (ms) | "
            "node CPU per answered pair (ms) | CPU used by the nodes | load average |"
        )
        print("|---:|---:|---:|---:|---:|---:|---:|")
        costs = [run_rigs(n, a.seconds, a.rate, env) for n in a.rigs]
        cost = float(np.median(costs))
        share = cost * a.rate / 1e3
        print(
            f"\nEach rig costs its node about {cost:.0f} ms of CPU per pair (median over the "
            f"rows), {100 * share:.0f} % of a core at {a.rate:g} Hz: this host's "
            f"{os.cpu_count()} cores would answer about {int(os.cpu_count() / share)} rigs "
            "completely if the nodes had them to themselves; the rows above show what they "
            "answered while sharing the cores with the publisher and other work (load average "
            "column)."
        )
        print(
            "\nA rig is answered completely while the nodes' CPU per pair times the pair rate "
            "of all rigs stays under the cores left by the drivers; past that each node drops "
            "the oldest pairs (its queue keeps the newest) and the share answered falls."
        )
    if a.write_docs:
        body = bench_docs.section(
            "bench_rigs",
            "Many rigs on one host (one node per rig)",
            bench_docs.command_line("bench_rigs.py", argv),
            out.text,
        )
        print(f"wrote {bench_docs.write_section('bench_rigs', body)}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
