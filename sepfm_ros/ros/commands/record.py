"""``sepfm_ros record -o OUT TOPIC...``: write live topics into a bag (like ``ros2 bag record``).

Each topic is subscribed as soon as a publisher of it is discovered, with its message type and a
QoS compatible with every publisher (reliable only when all offer reliable, transient local only
when all do); the offered QoS is stored with the topic. Messages are written as received (raw
CDR, log time = receipt time). Stops on Ctrl-C, SIGTERM or after ``--duration`` seconds.
Samples the middleware reports lost are counted per topic and reported at the end, with the
cause; large best-effort images arrive as in the node (``sepfm_ros.ros.node.dds``).

The bag is flushed every ``--flush-interval`` seconds (default 1): even a killed recorder leaves
a readable bag with everything up to the last flush; a clean stop keeps everything.

Exit codes: 0 recorded (a topic that never had a publisher is a warning), 1 an error (an output
name that exists or names another format, nothing recorded at all). Ctrl-C is the normal stop.
"""

from __future__ import annotations

import argparse
import signal
import sys
import time
from pathlib import Path

from sepfm_ros.ros.bags.errors import BagError
from sepfm_ros.ros.bags.writer import BagWriter, check_output_path
from sepfm_ros.ros.node.dds import configure_dds
from sepfm_ros.ros.node.recorder import Recorder
from sepfm_ros.ros.node.signals import raise_keyboard_interrupt


def _parse(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        prog="sepfm_ros record",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("topics", nargs="+", metavar="TOPIC")
    p.add_argument("-o", "--output", type=Path, required=True, help="output bag (must not exist)")
    p.add_argument("--duration", type=float, default=0.0, help="stop after S seconds (0 = never)")
    p.add_argument("--flush-interval", type=float, default=1.0, help="seconds (default 1)")
    return p.parse_args(argv)


def main(argv: list[str]) -> int:
    import rclpy
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor

    from sepfm_ros.ros.node.spin import own_arguments

    args = _parse(own_arguments("sepfm_ros record", "record", argv))
    try:
        check_output_path(args.output)
        if args.flush_interval <= 0:
            raise BagError("--flush-interval must be > 0")
        writer = BagWriter(args.output, flush_interval_s=args.flush_interval)
    except BagError as err:
        print(f"sepfm_ros record: error: {err}", file=sys.stderr)
        return 1
    dds = configure_dds()  # before rclpy creates the DDS participant
    rclpy.init(args=["record", *argv])
    previous = signal.signal(signal.SIGTERM, raise_keyboard_interrupt)
    node = rclpy.create_node("sepfm_record")
    recorder = Recorder(node, writer, args.topics)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    code = 0
    try:
        deadline = time.monotonic() + args.duration if args.duration > 0 else None
        while rclpy.ok() and (deadline is None or time.monotonic() < deadline):
            executor.spin_once(timeout_sec=0.1)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except BagError as err:
        print(f"sepfm_ros record: error: {err}", file=sys.stderr)
        code = 1
    finally:
        signal.signal(signal.SIGTERM, previous)
        recorder.close()
        node.destroy_node()
        rclpy.try_shutdown()
    missing = [t for t in recorder.topics if t not in recorder.subscriptions]
    summary = ", ".join(f"{t}: {recorder.counts[t]}" for t in recorder.topics)
    print(f"wrote {args.output} ({summary})", file=sys.stderr)
    lost = ", ".join(f"{t}: {recorder.lost[t]}" for t in recorder.topics if recorder.lost[t])
    if lost:
        advice = dds.lost_sample_advice("the recorder")
        print(f"sepfm_ros record: samples lost in transport ({lost}): {advice}", file=sys.stderr)
    if missing:
        print(
            f"sepfm_ros record: warning: never saw a publisher of {', '.join(missing)}",
            file=sys.stderr,
        )
    if code == 0 and not any(recorder.counts.values()):
        print(
            f"sepfm_ros record: error: nothing recorded: no message on {', '.join(args.topics)} "
            f"({args.output} holds no message)",
            file=sys.stderr,
        )
        code = 1
    return code
