"""A camera and the sepfm node on two "computers": two Linux network namespaces joined by a veth
pair whose both ends are rate-limited to 20 Mbit/s (``tc qdisc ... tbf``). Used by
test/ros/test_netns.py and benchmarks/bench_netns.py; needs root (CI runs as root).

- Namespace ``cam``: a camera process capturing a 10 Hz VGA colour stream (the 47 Temple Ring
  images of the shared data, 640x480 bgr8, looped), stamped at capture one period apart, and
  publishing each frame as
  ``/cam/image_raw`` (sensor_msgs/Image, 7.4 Mbit a frame: 74 Mbit/s, more than the link) or
  ``/cam/image_raw/compressed`` (JPEG, about 1.5 Mbit/s), reliable keep-last 10 as a camera
  driver's image_transport publisher. Fast DDS publishes synchronously: a publish blocks while
  the link's queue is full, and a frame captured meanwhile is dropped, as a camera driver drops
  the frames it cannot send; the stamps of the frames sent then skip periods.
- Namespace ``node``: the node (``mode:=motion``, its input remapped to ``/cam/image_raw``,
  ``image_transport`` raw or compressed; at ``nice -10``, above a shared machine's other work)
  and a probe that records the node's answers and its
  last ``/diagnostics`` report.

Discovery is the DDS default (SIMPLE discovery over multicast on the link; every participant
reaches the others, as on two computers of one LAN): the test session's localhost-only setting
(``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``) is replaced by ``SUBNET``, the ROS default. Each
namespace has a default route over the link, as a computer on a LAN has. Two computers share no
memory, so the camera process sends over UDP only (``FASTDDS_BUILTIN_TRANSPORTS=UDPv4``): with
Fast DDS's default shared-memory transport, processes of one host would bypass the link.

    sudo python benchmarks/netns_rig.py camera|probe ...   # the parts, run by run_link()
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
SHARED = REPO.parent / "shared" / "data"
RATE = "20mbit"
CAMERA_HZ = 10.0
TOPIC = "/cam/image_raw"
# the node's priority: above the host's other work (on a shared build machine), as on a robot's
# computer where the node does not compete with builds; the run measures the link, not the CPU
NODE_NICE = "-10"


def cannot_make_namespaces() -> str | None:
    """Why two network namespaces joined by a rate-limited veth pair cannot be made here, or
    None when they can (root, ``ip`` and ``tc``, and a trial namespace works)."""
    if os.geteuid() != 0:
        return "network namespaces need root (CI runs as root)"
    for tool in ("ip", "tc"):
        if shutil.which(tool) is None:
            return f"{tool} (iproute2) is not installed"
    name = f"sepfm_try{os.getpid()}"
    made = subprocess.run(["ip", "netns", "add", name], capture_output=True, text=True)
    if made.returncode != 0:
        return f"ip netns add failed: {made.stderr.strip()}"
    subprocess.run(["ip", "netns", "del", name], capture_output=True)
    return None


@dataclass
class Link:
    """Two namespaces ``cam`` and ``node`` joined by a veth pair limited to ``RATE``."""

    cam: str
    node: str
    cam_ip: str = "10.231.7.1"
    node_ip: str = "10.231.7.2"

    @classmethod
    def create(cls) -> Link:
        tag = os.getpid() % 100000
        link = cls(f"sepfm_cam{tag}", f"sepfm_node{tag}")
        try:
            link._setup(f"sfc{tag}", f"sfn{tag}")
        except subprocess.CalledProcessError as err:
            link.delete()
            raise RuntimeError(f"{' '.join(err.cmd)}: {err.stderr}") from None
        return link

    def _setup(self, veth_cam: str, veth_node: str) -> None:
        def ip(*args: str) -> None:
            subprocess.run(["ip", *args], check=True, capture_output=True, text=True)

        ip("netns", "add", self.cam)
        ip("netns", "add", self.node)
        ip("link", "add", veth_cam, "type", "veth", "peer", "name", veth_node)
        for ns, dev, addr, peer in (
            (self.cam, veth_cam, self.cam_ip, self.node_ip),
            (self.node, veth_node, self.node_ip, self.cam_ip),
        ):
            ip("link", "set", dev, "netns", ns)
            ip("-n", ns, "addr", "add", f"{addr}/24", "dev", dev)
            ip("-n", ns, "link", "set", dev, "up")
            ip("-n", ns, "link", "set", "lo", "up")
            ip("-n", ns, "route", "add", "default", "via", peer, "dev", dev)
            subprocess.run(
                ["ip", "netns", "exec", ns, "tc", "qdisc", "add", "dev", dev, "root", "tbf",
                 "rate", RATE, "burst", "32kbit", "latency", "400ms"],
                check=True, capture_output=True, text=True,
            )  # fmt: skip

    def delete(self) -> None:
        """Delete both namespaces (and with them the veth pair); never raises."""
        for ns in (self.cam, self.node):
            subprocess.run(["ip", "netns", "del", ns], capture_output=True)

    def exec(self, ns: str, args: list[str], log: Path, env: dict[str, str]) -> subprocess.Popen:
        """Start ``args`` in namespace ``ns``, output to ``log``."""
        out = open(log, "w")  # noqa: SIM115 - the child keeps it
        return subprocess.Popen(
            ["ip", "netns", "exec", ns, *args], cwd=REPO, env=env, stdout=out,
            stderr=subprocess.STDOUT,
        )  # fmt: skip


def link_env(domain_id: int) -> dict[str, str]:
    """The environment of every process of the run: DDS default discovery (see the module
    docstring) in ROS domain ``domain_id``."""
    env = dict(os.environ, PYTHONUNBUFFERED="1", RCUTILS_LOGGING_BUFFERED_STREAM="0")
    env["ROS_DOMAIN_ID"] = str(domain_id)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "SUBNET"
    for key in ("ROS_LOCALHOST_ONLY", "ROS_STATIC_PEERS", "FASTDDS_BUILTIN_TRANSPORTS"):
        env.pop(key, None)
    return env


@dataclass
class RunResult:
    """One cross-namespace run: the camera's frames, and what reached the node and came back."""

    transport: str
    frames: int  # frames the camera captured (10 Hz)
    published: int  # frames it published (a frame captured while a publish blocks is dropped)
    received: int  # frames the node received
    answered: int  # pairs answered (motion: one per received frame after the first)
    answered_share: float  # answered / (frames - 1): the pairs of the camera's stream
    frames_missing: int  # the node's count of frames missing from the stamp sequence
    lost_samples: int  # DDS lost samples the node counted
    dropped_pairs: int  # pairs the node dropped for newer ones while busy (CPU, not the link)
    level: int  # the node's last /diagnostics level
    message: str  # and its message
    warned_missing: bool  # a report named the frames missing
    latency_p50_ms: float  # camera stamp (publish time) -> answer at the probe
    latency_p95_ms: float


def run_link(
    transport: str, seconds: float, workdir: Path, domain_id: int, reliability: str = "reliable"
) -> RunResult:
    """Create the link, run the camera (``transport`` raw or compressed, ``seconds`` of stream,
    publisher ``reliability`` reliable or best_effort) and the node with a probe across it,
    delete the link; the run's figures."""
    workdir.mkdir(parents=True, exist_ok=True)
    env = link_env(domain_id)
    py = sys.executable
    link = Link.create()
    procs: list[subprocess.Popen] = []
    try:
        node = link.exec(
            link.node,
            ["nice", "-n", NODE_NICE, py, "-m", "sepfm_ros", "node", "--ros-args",
             "-p", "mode:=motion", "-p", f"image_transport:={transport}",
             "-r", f"image_raw:={TOPIC}", "-p", "diagnostics_period_s:=0.5"],
            workdir / f"node_{transport}.log", env,
        )  # fmt: skip
        procs.append(node)
        probe_out = workdir / f"probe_{transport}.json"
        probe = link.exec(
            link.node, [py, __file__, "probe", "--out", str(probe_out)],
            workdir / f"probe_{transport}.log", env,
        )  # fmt: skip
        procs.append(probe)
        cam_out = workdir / f"camera_{transport}.json"
        camera = link.exec(
            link.cam,
            [py, __file__, "camera", "--transport", transport, "--seconds", str(seconds),
             "--out", str(cam_out), "--reliability", reliability],
            workdir / f"camera_{transport}.log", dict(env, FASTDDS_BUILTIN_TRANSPORTS="UDPv4"),
        )  # fmt: skip
        procs.append(camera)
        if camera.wait(timeout=seconds + 300) != 0:
            log = (workdir / f"camera_{transport}.log").read_text()
            raise RuntimeError(f"camera failed: {log}")
        time.sleep(4.0)  # the last answers and a /diagnostics report after them
        probe.send_signal(signal.SIGINT)
        probe.wait(timeout=60)
        if not probe_out.is_file():
            raise RuntimeError(f"probe failed: {(workdir / f'probe_{transport}.log').read_text()}")
        cam, answers = json.loads(cam_out.read_text()), json.loads(probe_out.read_text())
        return _result(transport, cam, answers)
    finally:
        for proc in reversed(procs):
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
                try:
                    proc.wait(timeout=20)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()
        link.delete()


def _result(transport: str, cam: dict, probe: dict) -> RunResult:
    import numpy as np

    stamps = cam["stamps"]
    answers = probe["answers"]  # stamp -> receipt wall time, ns
    latencies = [(answers[str(s)] - s) / 1e6 for s in stamps if str(s) in answers]
    values = probe["values"]
    return RunResult(
        transport,
        int(cam["frames"]),
        len(stamps),
        int(values.get("received_image", 0)),
        len(latencies),
        len(latencies) / max(1, int(cam["frames"]) - 1),
        int(values.get("frames_missing", 0)),
        int(values.get("lost_samples", 0)),
        int(values.get("dropped_pairs", 0)),
        int(probe["level"]),
        probe["message"],
        bool(probe["warned_missing"]),
        float(np.percentile(latencies, 50)) if latencies else float("nan"),
        float(np.percentile(latencies, 95)) if latencies else float("nan"),
    )


# ------------------------------------------------------------------------ the two processes
def camera_main(transport: str, seconds: float, out: Path, reliability: str) -> None:
    """Publish ``seconds`` of a 10 Hz stream once the node's subscription matched; write the
    published stamps to ``out``."""
    import cv2
    import rclpy
    from builtin_interfaces.msg import Time
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import CompressedImage, Image
    from std_msgs.msg import Header

    from sepfm_ros.ros.msgs.image_conversion import numpy_to_compressed, numpy_to_image

    frames = [cv2.imread(str(p)) for p in sorted((SHARED / "templeRing").glob("*.png"))]
    rclpy.init()
    node = rclpy.create_node("camera")
    policy = ReliabilityPolicy.RELIABLE
    if reliability == "best_effort":
        policy = ReliabilityPolicy.BEST_EFFORT
    qos = QoSProfile(depth=10, reliability=policy)
    compressed = transport == "compressed"
    pub = node.create_publisher(
        CompressedImage if compressed else Image, TOPIC + ("/compressed" if compressed else ""), qos
    )
    deadline = time.monotonic() + 120
    while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
        time.sleep(0.1)
    if pub.get_subscription_count() == 0:
        raise SystemExit("the node did not subscribe across the link within 120 s")
    time.sleep(2.0)  # the node's side of the match
    period_ns = int(1e9 / CAMERA_HZ)
    start = (time.time_ns() // period_ns + 1) * period_ns
    stamps = []
    frames_total = int(seconds * CAMERA_HZ)
    for k in range(frames_total):
        stamp = start + k * period_ns  # captured at 10 Hz
        late = time.time_ns() - stamp
        if late > period_ns:
            continue  # the previous publish took longer than a period: this frame is gone
        time.sleep(max(0.0, -late / 1e9))
        image = frames[k % len(frames)]
        header = Header(stamp=Time(sec=stamp // 10**9, nanosec=stamp % 10**9), frame_id="camera")
        msg = (
            numpy_to_compressed(image, "jpeg", header)
            if compressed
            else numpy_to_image(image, "bgr8", header)
        )
        pub.publish(msg)
        stamps.append(stamp)
    time.sleep(2.0)  # let the writer's last samples go
    out.write_text(json.dumps({"stamps": stamps, "frames": frames_total, "start": start}))
    node.destroy_node()
    rclpy.shutdown()


def probe_main(out: Path) -> None:
    """Record the node's answers (stamp -> receipt wall time) and its /diagnostics until SIGINT;
    write them to ``out``."""
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import ExternalShutdownException
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    from sepfm_msgs.msg import TwoViewEstimate
    from sepfm_ros.ros.msgs.diagnostics import status_values
    from sepfm_ros.ros.msgs.headers import stamp_ns

    rclpy.init()
    node = rclpy.create_node("probe")
    qos = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
    answers: dict[int, int] = {}
    state: dict = {"values": {}, "level": -1, "message": "", "warned_missing": False}

    def on_estimate(msg: TwoViewEstimate) -> None:
        answers[stamp_ns(msg.header.stamp)] = time.time_ns()

    def on_diagnostics(msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name.endswith(": node") and "sepfm" in status.name:
                state["values"] = status_values(status)
                state["level"] = int.from_bytes(status.level, "little")
                state["message"] = status.message
                if "missing from the camera stamp" in status.message:
                    state["warned_missing"] = True

    node.create_subscription(TwoViewEstimate, "/sepfm/estimate", on_estimate, qos)
    node.create_subscription(DiagnosticArray, "/diagnostics", on_diagnostics, qos)
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):  # SIGINT: either, by its timing
        pass
    out.write_text(json.dumps({"answers": {str(k): v for k, v in answers.items()}, **state}))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    sub = p.add_subparsers(dest="part", required=True)
    cam = sub.add_parser("camera")
    cam.add_argument("--transport", choices=("raw", "compressed"), required=True)
    cam.add_argument("--seconds", type=float, required=True)
    cam.add_argument("--out", type=Path, required=True)
    cam.add_argument("--reliability", choices=("reliable", "best_effort"), default="reliable")
    probe = sub.add_parser("probe")
    probe.add_argument("--out", type=Path, required=True)
    args = p.parse_args()
    if args.part == "camera":
        camera_main(args.transport, args.seconds, args.out, args.reliability)
    else:
        probe_main(args.out)


if __name__ == "__main__":
    main()
