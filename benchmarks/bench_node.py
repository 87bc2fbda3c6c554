"""Benchmark of the live node against the same pipeline without ROS.

    python benchmarks/bench_node.py [--seconds 10] [--rate 30] [--features orb]
        [--max-features 1000] [--method sep5] [--scenes NAME ...]

For each scene (templeRing 640x480: consecutive views as a left/right pair; KITTI stereo
1241x376) it prints:

- ``pipeline``: the Pipeline called directly on decoded images (no ROS), pairs/s and per-stage ms;
- ``pipeline 2 threads``: the same, matching pair n+1 on a second thread while pair n is
  estimated, as the node does (the most the node could reach without ROS);
- ``node @R Hz``: the node subprocess fed pairs at R pairs/s over DDS for the given time:
  answered pairs/s, dropped pairs, latency receipt->publish p50/p95 (the node's own clock),
  end-to-end latency (stamp -> answer received here) p50/p95, worst wait before processing
  (receipt -> start), the node process's CPU time per answered pair (robust to other load on
  the machine), and the per-stage split including decode, queue (matched pair waiting for the
  estimate thread) and publish;
- ``node closed loop``: the next pair is sent as soon as the previous answer arrived (the most
  the node sustains without dropping).

Targets (issue 3): >= 30 pairs/s at 640x480 with ORB 1000 features, p95 latency <= 60 ms, no
frame processed more than 100 ms after receipt. Reads ../shared/data. Uses a random
ROS_DOMAIN_ID unless one is set.
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
from collections import defaultdict
from pathlib import Path

import cv2
import numpy as np

REPO = Path(__file__).resolve().parent.parent
DATA = REPO.parent / "shared" / "data"
SCENES = {
    "templeRing 640x480": [
        (f"templeRing/templeR{k:04d}.png", f"templeRing/templeR{k + 1:04d}.png")
        for k in range(1, 12)
    ],
    "KITTI stereo 1241x376": [
        (f"kitti_seq2/left/{k:06d}.png", f"kitti_seq2/right/{k:06d}.png") for k in range(0, 11)
    ],
}
STAGES = ("decode", "features", "match", "lines", "stage1", "stage2", "refine", "estimate")
STAGES += ("queue", "publish", "total")


def pct(values, q):
    return float(np.percentile(values, q)) if len(values) else float("nan")


def stage_line(per_stage: dict[str, list[float]]) -> str:
    return "  ".join(
        f"{s} {np.mean(per_stage[s]):.1f}" for s in STAGES if per_stage.get(s)
    )  # fmt: skip


def cpu_seconds(pid: int | None = None) -> float:
    """User + system CPU seconds of process ``pid`` (all its threads; None = this process)."""
    if pid is None:
        return time.process_time()
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def bench_pipeline(pairs, args) -> None:
    from sepfm_ros.pipeline.pipeline import Pipeline, PipelineConfig
    from sepfm_ros.ros.node import limit_thread_pools

    limit_thread_pools(1)  # as in the node
    pipeline = Pipeline(
        PipelineConfig(features=args.features, max_features=args.max_features, method=args.method)
    )
    cpu0 = cpu_seconds()
    per_stage: dict[str, list[float]] = defaultdict(list)
    totals = []
    deadline = time.monotonic() + args.seconds
    n = 0
    while time.monotonic() < deadline:
        a, b = pairs[n % len(pairs)]
        result = pipeline.process(a, b)
        for stage, ms in result.timings_ms.items():
            per_stage[stage].append(ms)
        totals.append(result.timings_ms["total"])
        n += 1
    print(
        f"  pipeline (no ROS)   {1000.0 / np.mean(totals):6.1f} pairs/s"
        f"  p50 {pct(totals, 50):.1f} ms  p95 {pct(totals, 95):.1f} ms  [{n} pairs]"
        f"  CPU {(cpu_seconds() - cpu0) * 1e3 / n:.1f} ms/pair"
    )
    print(f"      stages ms: {stage_line(per_stage)}")
    bench_pipeline_threaded(pipeline, pairs, args)


def bench_pipeline_threaded(pipeline, pairs, args) -> None:
    """Match pair n+1 on a second thread while pair n is estimated (the node's two stages)."""
    from concurrent.futures import ThreadPoolExecutor

    cpu0 = cpu_seconds()
    start = time.perf_counter()
    deadline = time.monotonic() + args.seconds
    n = 0
    with ThreadPoolExecutor(1) as matcher:
        pending = matcher.submit(pipeline.match, *pairs[0])
        while time.monotonic() < deadline:
            matched = pending.result()
            pending = matcher.submit(pipeline.match, *pairs[(n + 1) % len(pairs)])
            pipeline.estimate(matched)
            n += 1
        pending.result()
    elapsed = time.perf_counter() - start
    print(
        f"  pipeline 2 threads  {n / elapsed:6.1f} pairs/s  [{n} pairs]"
        f"  CPU {(cpu_seconds() - cpu0) * 1e3 / n:.1f} ms/pair"
    )


class Feeder:
    """Test-side rclpy node: publishes pairs, collects ~/estimate_info."""

    def __init__(self, node_name: str) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import Image

        self.rclpy = rclpy
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node("sepfm_bench", context=self.context)
        qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self.left = self.node.create_publisher(Image, "/bench/left/image_raw", qos)
        self.right = self.node.create_publisher(Image, "/bench/right/image_raw", qos)
        self.lock = threading.Lock()
        self.answers: dict[int, tuple[float, dict[str, str]]] = {}
        self.node.create_subscription(
            DiagnosticArray, f"/{node_name}/estimate_info", self._on_info, qos
        )
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self):
        try:
            self.executor.spin()
        except Exception:  # noqa: BLE001 - shut down at exit
            pass

    def _on_info(self, msg):
        now = time.time()
        stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
        values = {kv.key: kv.value for kv in msg.status[0].values}
        with self.lock:
            self.answers[stamp] = (now, values)

    def wait_connected(self, timeout=30.0):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.left.get_subscription_count() and self.right.get_subscription_count():
                time.sleep(0.5)
                return
            time.sleep(0.05)
        raise RuntimeError("node did not subscribe")

    def send(self, msgs, stamp: int) -> None:
        left, right = msgs
        for msg in (left, right):
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 10**9)
        self.left.publish(left)
        self.right.publish(right)

    def close(self):
        self.executor.shutdown()
        self.node.destroy_node()
        self.rclpy.try_shutdown(context=self.context)


def summarize(label, feeder, sent_stamps, seconds, cpu_s):
    time.sleep(1.0)
    with feeder.lock:
        got = [feeder.answers[s] for s in sent_stamps if s in feeder.answers]
        e2e = [(t - s / 1e9) * 1e3 for s in sent_stamps if s in feeder.answers
               for t in [feeder.answers[s][0]]]  # fmt: skip
    per_stage: dict[str, list[float]] = defaultdict(list)
    latency, wait = [], []
    for _, values in got:
        for key, value in values.items():
            if key.startswith("ms_"):
                per_stage[key[3:]].append(float(value))
        latency.append(float(values["ms_latency"]))
        wait.append(float(values["ms_wait"]))
    print(
        f"  {label:<19} {len(got) / seconds:6.1f} pairs/s  answered {len(got)}/{len(sent_stamps)}"
        f"  latency p50 {pct(latency, 50):.1f} p95 {pct(latency, 95):.1f} ms"
        f"  end-to-end p50 {pct(e2e, 50):.1f} p95 {pct(e2e, 95):.1f} ms"
        f"  max wait {max(wait, default=float('nan')):.1f} ms"
        f"  node CPU {cpu_s * 1e3 / max(1, len(got)):.1f} ms/pair"
    )
    print(f"      stages ms: {stage_line(per_stage)}")


def bench_node(pairs, args, name: str) -> None:
    from sepfm_ros.ros.image_conversion import numpy_to_image

    node_name = "sepfm_bench_node"
    cmd = [sys.executable, "-m", "sepfm_ros", "node", "--ros-args", "-r", f"__node:={node_name}"]
    cmd += ["-r", "left/image_raw:=/bench/left/image_raw"]
    cmd += ["-r", "right/image_raw:=/bench/right/image_raw"]
    cmd += ["-p", f"features:={args.features}", "-p", f"max_features:={args.max_features}"]
    cmd += ["-p", f"method:={args.method}"]
    for side in ("left", "right"):
        cmd += ["-p", f"qos_overrides./bench/{side}/image_raw.subscription.reliability:=reliable"]
    proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT)
    feeder = Feeder(node_name)
    try:
        feeder.wait_connected()
        msgs = [(numpy_to_image(a, "mono8"), numpy_to_image(b, "mono8")) for a, b in pairs]
        # warm-up
        for k in range(3):
            stamp = time.time_ns()
            feeder.send(msgs[k % len(msgs)], stamp)
            time.sleep(0.3)
        # paced at args.rate pairs/s
        cpu0 = cpu_seconds(proc.pid)
        sent = []
        period = 1.0 / args.rate
        start = time.monotonic()
        k = 0
        while time.monotonic() - start < args.seconds:
            target = start + k * period
            time.sleep(max(0.0, target - time.monotonic()))
            stamp = time.time_ns()
            feeder.send(msgs[k % len(msgs)], stamp)
            sent.append(stamp)
            k += 1
        cpu_s = cpu_seconds(proc.pid) - cpu0
        summarize(f"node @{args.rate:g} Hz", feeder, sent, args.seconds, cpu_s)
        # closed loop
        cpu0 = cpu_seconds(proc.pid)
        sent = []
        start = time.monotonic()
        k = 0
        while time.monotonic() - start < args.seconds:
            stamp = time.time_ns()
            feeder.send(msgs[k % len(msgs)], stamp)
            sent.append(stamp)
            k += 1
            deadline = time.monotonic() + 5.0
            while time.monotonic() < deadline:
                with feeder.lock:
                    if stamp in feeder.answers:
                        break
                time.sleep(0.0005)
        elapsed = time.monotonic() - start
        cpu_s = cpu_seconds(proc.pid) - cpu0
        summarize("node closed loop", feeder, sent, elapsed, cpu_s)
    finally:
        feeder.close()
        proc.send_signal(signal.SIGINT)
        proc.wait(15)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--rate", type=float, default=30.0, help="paced input rate, pairs/s")
    parser.add_argument("--features", default="orb")
    parser.add_argument("--max-features", type=int, default=1000)
    parser.add_argument("--method", default="sep5")
    parser.add_argument("--scenes", nargs="*", default=list(SCENES))
    args = parser.parse_args()
    if not DATA.is_dir():
        print(f"shared data not found at {DATA}", file=sys.stderr)
        return 2
    os.environ.setdefault("ROS_DOMAIN_ID", str(random.SystemRandom().randint(1, 200)))
    print(
        f"method {args.method}, features {args.features}, max_features {args.max_features},"
        f" {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f},"
        f" ROS_DOMAIN_ID {os.environ['ROS_DOMAIN_ID']}; stage times are means"
    )
    for name in args.scenes:
        pairs = [
            (cv2.imread(str(DATA / a), cv2.IMREAD_GRAYSCALE), cv2.imread(str(DATA / b), 0))
            for a, b in SCENES[name]
        ]
        print(f"{name}:")
        bench_pipeline(pairs, args)
        bench_node(pairs, args, name)
        print(f"  (load average now {os.getloadavg()[0]:.1f})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
