"""Benchmark of the live node against the same pipeline without ROS.

    python benchmarks/bench_node.py [--seconds 10] [--rate 30] [--features orb]
        [--max-features 1000] [--method sep5] [--scenes NAME ...]
        [--publisher-qos default sensor_data] [--write-docs]

The node runs at its default settings (no QoS override), fed by a publisher with the QoS a camera
driver uses: ROS 2's default (reliable) or sensor-data (best effort), one node per QoS.
``--write-docs`` rewrites this script's section of docs/benchmarks.md (see bench_docs.py).

For each scene it prints (templeRing 640x480 in motion mode: the 47 views of the ring as one
image stream, F between consecutive views, each frame detected once; KITTI stereo 1241x376:
left/right pairs; templeRing stereo: consecutive views sent as left/right pairs, both detected
every time):

- ``pipeline``: the Pipeline called directly on decoded images (no ROS, the node's default
  config; in motion mode features cached per frame as the node does), pairs/s and per-stage ms;
- ``pipeline 2 threads``: the same, matching pair n+1 on a second thread while pair n is
  estimated (the two stages fully overlapped; the node itself hands over instead when
  saturated, see sepfm_ros/ros/node.py);
- ``node @R Hz``: the node subprocess fed pairs at R pairs/s over DDS for the given time:
  answered pairs/s, dropped pairs, latency receipt->publish p50/p95 (the node's own clock),
  end-to-end latency (stamp -> answer received here) p50/p95, worst wait before processing
  (receipt -> start), the node process's CPU time per answered pair (robust to other load on
  the machine) and its split by thread (executor = the main thread, sepfm-match, sepfm-detect,
  sepfm-estimate, DDS threads; from /proc), and the per-stage split including decode, queue
  (matched pair waiting for the estimate thread) and publish;
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

import bench_docs
import cv2
import numpy as np

from sepfm_ros.geometry import DEFAULT_METHOD

REPO = Path(__file__).resolve().parent.parent
DATA = REPO.parent / "shared" / "data"
# scene -> (node mode, images): motion = one stream of frames (F between consecutive frames; the
# templeRing views form a ring, so the last view and the first are neighbours too); stereo =
# (left, right) pairs
SCENES = {
    "templeRing 640x480 motion": (
        "motion",
        [f"templeRing/templeR{k:04d}.png" for k in range(1, 48)],
    ),
    "KITTI stereo 1241x376": (
        "stereo",
        [(f"kitti_seq2/left/{k:06d}.png", f"kitti_seq2/right/{k:06d}.png") for k in range(0, 11)],
    ),
    "templeRing 640x480 stereo": (
        "stereo",
        [
            (f"templeRing/templeR{k:04d}.png", f"templeRing/templeR{k + 1:04d}.png")
            for k in range(1, 12)
        ],
    ),
}
# colour camera streams as a user's driver publishes them (bgr8; the 1920x1080 one upscaled, so
# it measures rate, not accuracy: bench_downscale.py measures that on native 1536x1024 frames;
# at the default feature_max_width its features are found at 960x540)
SCENES["templeRing 640x480 bgr8 motion"] = (
    "motion",
    [f"templeRing/templeR{k:04d}.png" for k in range(1, 48)],
)
SCENES["templeRing 1920x1080 bgr8 motion"] = SCENES["templeRing 640x480 bgr8 motion"]
COLOUR_SIZES = {
    "templeRing 640x480 bgr8 motion": None,
    "templeRing 1920x1080 bgr8 motion": (1920, 1080),
}
DEFAULT_SCENES = (
    "templeRing 640x480 motion",
    "KITTI stereo 1241x376",
    "templeRing 640x480 bgr8 motion",
    "templeRing 1920x1080 bgr8 motion",
)
# publisher QoS of the feeding "camera driver": ROS 2's default (reliable, keep-last 10) or the
# sensor-data profile (best effort, keep-last 5); the node runs at its default settings and
# adapts its subscription to what is offered
PUBLISHER_QOS = ("default", "sensor_data")
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


def thread_cpu(pid: int) -> dict[str, float]:
    """CPU seconds of process ``pid`` per thread name (the main thread is the executor)."""
    out: dict[str, float] = defaultdict(float)
    tick = os.sysconf("SC_CLK_TCK")
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            comm = (task / "comm").read_text().strip()
            fields = (task / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:  # the thread ended meanwhile
            continue
        name = "executor" if task.name == str(pid) else comm
        out[name] += (int(fields[11]) + int(fields[12])) / tick
    return out


def thread_line(before: dict[str, float], after: dict[str, float], pairs: int) -> str:
    """Node CPU ms per answered pair by thread (largest first; threads below 0.05 ms left out)."""
    per = {k: (after.get(k, 0.0) - before.get(k, 0.0)) * 1e3 / max(1, pairs) for k in after}
    return "  ".join(f"{k} {v:.1f}" for k, v in sorted(per.items(), key=lambda kv: -kv[1])
                     if v >= 0.05)  # fmt: skip


def node_values(args) -> dict:
    """The node's parameter values for this run: its defaults with the command-line changes."""
    from sepfm_ros.ros.session.parameters import PARAMS

    values = {name: spec.default for name, spec in PARAMS.items()}
    values.update(features=args.features, max_features=args.max_features, method=args.method)
    for item in args.param:
        name, _, text = item.partition(":=")
        default = PARAMS[name].default
        values[name] = type(default)(float(text)) if isinstance(default, int | float) else text
    return values


def pipeline_steps(mode: str, images: list) -> list[tuple]:
    """One loop of (image_a, image_b, key_a, key_b) as the node sees them (keys = frame ids)."""
    if mode == "stereo":
        return [(a, b, None, None) for a, b in images]
    n = len(images)
    return [(images[k], images[(k + 1) % n], k, (k + 1) % n) for k in range(n)]


def bench_pipeline(mode, images, args) -> None:
    from sepfm_ros.pipeline.compiled import warm_up
    from sepfm_ros.pipeline.pipeline import Pipeline
    from sepfm_ros.ros.node.spin import limit_thread_pools
    from sepfm_ros.ros.session.parameters import pipeline_config

    limit_thread_pools(1)  # as in the node
    warm_up()  # as the node does before its first frame: compiling is not timed
    # as in the node: features cached per frame, the two images of a stereo pair detected at once
    pipeline = Pipeline(pipeline_config(node_values(args)), cache_size=8, parallel_detect=True)
    steps = pipeline_steps(mode, images)
    for step in steps[:3]:
        pipeline.process(*step)
    cpu0 = cpu_seconds()
    per_stage: dict[str, list[float]] = defaultdict(list)
    totals = []
    deadline = time.monotonic() + args.seconds
    n = 0
    while time.monotonic() < deadline:
        result = pipeline.process(*steps[n % len(steps)])
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
    bench_pipeline_threaded(pipeline, steps, args)


def bench_pipeline_threaded(pipeline, steps, args) -> None:
    """Match pair n+1 on a second thread while pair n is estimated (the node's two stages)."""
    from concurrent.futures import ThreadPoolExecutor

    cpu0 = cpu_seconds()
    start = time.perf_counter()
    deadline = time.monotonic() + args.seconds
    n = 0
    with ThreadPoolExecutor(1) as matcher:
        pending = matcher.submit(pipeline.match, *steps[0])
        while time.monotonic() < deadline:
            matched = pending.result()
            pending = matcher.submit(pipeline.match, *steps[(n + 1) % len(steps)])
            pipeline.estimate(matched)
            n += 1
        pending.result()
    elapsed = time.perf_counter() - start
    print(
        f"  pipeline 2 threads  {n / elapsed:6.1f} pairs/s  [{n} pairs]"
        f"  CPU {(cpu_seconds() - cpu0) * 1e3 / n:.1f} ms/pair"
    )


class Feeder:
    """Test-side rclpy node: publishes pairs (stereo) or frames (motion), collects answers."""

    def __init__(self, node_name: str, mode: str, publisher_qos: str) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
        from sensor_msgs.msg import Image

        from sepfm_msgs.msg import TwoViewEstimate

        self.rclpy = rclpy
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node("sepfm_bench", context=self.context)
        qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        camera_qos = qos if publisher_qos == "default" else qos_profile_sensor_data
        topics = ("left", "right") if mode == "stereo" else ("",)
        self.pubs = [
            self.node.create_publisher(Image, f"/bench/{t}{'/' if t else ''}image_raw", camera_qos)
            for t in topics
        ]
        self.lock = threading.Lock()
        self.answers: dict[int, tuple[float, dict[str, float]]] = {}  # stamp -> (time, ms)
        self.node.create_subscription(
            TwoViewEstimate, f"/{node_name}/estimate", self._on_estimate, qos
        )
        self.health: dict[str, str] = {}  # the node's latest /diagnostics values
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_health, qos)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self):
        # spin_once until close() sets stop: the thread ends before the executor, node and
        # context are torn down (executor.spin() racing that teardown could spin hot holding
        # the GIL and starve the main thread's wait for the node process)
        try:
            while not self.stop.is_set():
                self.executor.spin_once(timeout_sec=0.05)
        except Exception:  # noqa: BLE001 - shut down at exit
            pass

    def _on_health(self, msg):
        for status in msg.status:
            if status.name.endswith(": node"):
                with self.lock:
                    self.health = {kv.key: kv.value for kv in status.values}

    def _on_estimate(self, msg):
        now = time.time()
        stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
        timings = {t.stage: t.ms for t in msg.timings}
        with self.lock:
            self.answers[stamp] = (now, timings)

    def wait_connected(self, timeout=240.0):  # a cold numba cache: the node compiles first
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if all(p.get_subscription_count() for p in self.pubs):
                time.sleep(0.5)
                return
            time.sleep(0.05)
        raise RuntimeError("node did not subscribe")

    def send(self, msgs, stamp: int) -> None:
        """Publish one pair (stereo) or one frame (motion) under ``stamp``."""
        for msg in msgs:
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 10**9)
        for pub, msg in zip(self.pubs, msgs, strict=True):
            pub.publish(msg)

    def wait_answer(self, stamp: int, timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            with self.lock:
                if stamp in self.answers:
                    return True
            time.sleep(0.0005)
        return False

    def close(self):
        self.stop.set()
        self.thread.join(timeout=5.0)
        self.executor.shutdown()
        self.node.destroy_node()
        self.rclpy.try_shutdown(context=self.context)


def summarize(label, feeder, sent_stamps, seconds, cpu_s, threads=None):
    time.sleep(1.0)
    with feeder.lock:
        got = [feeder.answers[s] for s in sent_stamps if s in feeder.answers]
        e2e = [(t - s / 1e9) * 1e3 for s in sent_stamps if s in feeder.answers
               for t in [feeder.answers[s][0]]]  # fmt: skip
    per_stage: dict[str, list[float]] = defaultdict(list)
    latency, wait = [], []
    for _, timings in got:
        for stage, ms in timings.items():
            per_stage[stage].append(ms)
        latency.append(timings["latency"])
        wait.append(timings["wait"])
    print(
        f"  {label:<19} {len(got) / seconds:6.1f} pairs/s  answered {len(got)}/{len(sent_stamps)}"
        f" ({100.0 * len(got) / max(1, len(sent_stamps)):.1f}%)"
        f"  latency p50 {pct(latency, 50):.1f} p95 {pct(latency, 95):.1f} ms"
        f"  end-to-end p50 {pct(e2e, 50):.1f} p95 {pct(e2e, 95):.1f} ms"
        f"  max wait {max(wait, default=float('nan')):.1f} ms"
        f"  node CPU {cpu_s * 1e3 / max(1, len(got)):.1f} ms/pair"
    )
    print(f"      stages ms: {stage_line(per_stage)}")
    if threads is not None:
        print(f"      node CPU ms/pair by thread: {thread_line(*threads, len(got))}")


def bench_node(mode, images, args, publisher_qos: str) -> None:
    from sepfm_ros.ros.msgs.image_conversion import numpy_to_image

    node_name = "sepfm_bench_node"
    cmd = [sys.executable, "-m", "sepfm_ros", "node", "--ros-args", "-r", f"__node:={node_name}"]
    cmd += ["-p", f"mode:={mode}"]
    topics = ("left/image_raw", "right/image_raw") if mode == "stereo" else ("image_raw",)
    for topic in topics:  # no QoS override: the node's default subscription
        cmd += ["-r", f"{topic}:=/bench/{topic}"]
    cmd += ["-p", f"features:={args.features}", "-p", f"max_features:={args.max_features}"]
    cmd += ["-p", f"method:={args.method}"]
    for item in args.param:
        cmd += ["-p", item]
    proc = subprocess.Popen(
        cmd, cwd=REPO, env=args.node_env, stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT
    )
    feeder = Feeder(node_name, mode, publisher_qos)
    try:
        feeder.wait_connected()

        def msg(image):
            return numpy_to_image(image, "bgr8" if image.ndim == 3 else "mono8")

        if mode == "stereo":
            msgs = [(msg(a), msg(b)) for a, b in images]
        else:
            msgs = [(msg(a),) for a in images]
        # warm-up until 3 answers (motion mode: the first frame has no pair, so no answer); one
        # frame counter throughout, so that a motion stream always pairs neighbouring views
        # (the node subscribes after loading its kernels, so it is warm by now)
        frame, answered, deadline = 0, 0, time.monotonic() + 60.0
        while answered < 3:
            if time.monotonic() > deadline:
                with feeder.lock:
                    health = dict(feeder.health)
                got = {k: v for k, v in health.items() if k.startswith(("received_", "lost_"))}
                reliability = {k: v for k, v in health.items() if "reliability" in k}
                print(
                    f"  node {publisher_qos:<14} answered {answered} of {frame} pairs in 60 s;"
                    f" node: {got} {reliability}"
                )
                return
            stamp = time.time_ns()
            feeder.send(msgs[frame % len(msgs)], stamp)
            frame += 1
            answered += feeder.wait_answer(stamp, 10.0)
        # paced at args.rate pairs/s (motion mode: frames/s, one pair per frame)
        cpu0, threads0 = cpu_seconds(proc.pid), thread_cpu(proc.pid)
        sent = []
        period = 1.0 / args.rate
        start = time.monotonic()
        k = 0
        while time.monotonic() - start < args.seconds:
            target = start + k * period
            time.sleep(max(0.0, target - time.monotonic()))
            stamp = time.time_ns()
            feeder.send(msgs[frame % len(msgs)], stamp)
            frame += 1
            sent.append(stamp)
            k += 1
        cpu_s, threads = cpu_seconds(proc.pid) - cpu0, (threads0, thread_cpu(proc.pid))
        summarize(
            f"node @{args.rate:g} Hz {publisher_qos}", feeder, sent, args.seconds, cpu_s, threads
        )
        # closed loop
        cpu0, threads0 = cpu_seconds(proc.pid), thread_cpu(proc.pid)
        sent = []
        start = time.monotonic()
        while time.monotonic() - start < args.seconds:
            stamp = time.time_ns()
            feeder.send(msgs[frame % len(msgs)], stamp)
            frame += 1
            sent.append(stamp)
            # a pair lost on the way (best effort) must not stall the loop for the whole window
            feeder.wait_answer(stamp, 1.0)
        elapsed = time.monotonic() - start
        cpu_s, threads = cpu_seconds(proc.pid) - cpu0, (threads0, thread_cpu(proc.pid))
        summarize(f"node closed loop {publisher_qos}", feeder, sent, elapsed, cpu_s, threads)
    finally:
        feeder.close()
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(15)
        except subprocess.TimeoutExpired:  # never leave a node running (it would load the cores)
            proc.kill()
            proc.wait()


def _grey(image: np.ndarray) -> np.ndarray:
    """The node decodes to mono8; the pipeline runs on that."""
    return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--rate", type=float, default=30.0, help="paced input rate, pairs/s")
    parser.add_argument("--features", default="orb")
    parser.add_argument("--max-features", type=int, default=1000)
    parser.add_argument("--method", default=DEFAULT_METHOD)
    parser.add_argument(
        "--param",
        action="append",
        default=[],
        metavar="NAME:=VALUE",
        help="another node parameter (numeric or string), also used by the pipeline runs",
    )
    parser.add_argument("--scenes", nargs="*", default=list(DEFAULT_SCENES), choices=SCENES)
    parser.add_argument(
        "--publisher-qos",
        nargs="*",
        default=list(PUBLISHER_QOS),
        choices=PUBLISHER_QOS,
        help="QoS of the feeding publisher (the node keeps its default settings)",
    )
    parser.add_argument(
        "--write-docs", action="store_true", help="rewrite this section of docs/benchmarks.md"
    )
    args = parser.parse_args(argv)
    if not DATA.is_dir():
        print(f"shared data not found at {DATA}", file=sys.stderr)
        return 2
    os.environ.setdefault("ROS_DOMAIN_ID", str(random.SystemRandom().randint(1, 200)))
    # the node runs in the caller's environment (a user's default: no discovery range set, where
    # the node picks its input transport, see sepfm_ros/ros/dds.py); this process's feeder keeps
    # discovery on this machine
    args.node_env = dict(os.environ)
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    with bench_docs.captured_stdout() as out:
        run_scenes(args)
    if args.write_docs:
        title = f"Node benchmark ({args.method}, {args.features} {args.max_features})"
        command = bench_docs.command_line("bench_node.py", argv)
        body = f"```text\n{out.text.strip()}\n```"
        path = bench_docs.write_section(
            "bench_node", bench_docs.section("bench_node", title, command, body)
        )
        print(f"wrote {path}", file=sys.stderr)
    return 0


def run_scenes(args: argparse.Namespace) -> None:
    """Pipeline and node figures of every scene in ``args.scenes``, printed."""
    print(
        f"method {args.method}, features {args.features}, max_features {args.max_features},"
        f" feature_max_width {node_values(args)['feature_max_width']},"
        f" {' '.join(args.param)} {os.cpu_count()} CPUs, load average"
        f" {os.getloadavg()[0]:.1f}, ROS_DOMAIN_ID {os.environ['ROS_DOMAIN_ID']};"
        " stage times are means"
    )

    for name in args.scenes:
        mode, names = SCENES[name]
        colour = name in COLOUR_SIZES

        size = COLOUR_SIZES.get(name)

        def read(rel, colour=colour, size=size):
            flag = cv2.IMREAD_COLOR if colour else cv2.IMREAD_GRAYSCALE
            image = cv2.imread(str(DATA / rel), flag)
            return image if size is None else cv2.resize(image, size)

        if mode == "stereo":
            images = [(read(a), read(b)) for a, b in names]
        else:
            images = [read(a) for a in names]
        print(f"{name}:")
        bench_pipeline(mode, [_grey(i) for i in images] if colour else images, args)
        for publisher_qos in args.publisher_qos:
            bench_node(mode, images, args, publisher_qos)
        print(f"  (load average now {os.getloadavg()[0]:.1f})")


if __name__ == "__main__":
    raise SystemExit(main())
