"""``sepfm_ros replay BAG``: publish a bag into live topics with its recorded timing.

Like ``ros2 bag play`` (not available from PyPI): BAG is a rosbag2 bag (sqlite3 or mcap) or a
ROS 1 ``.bag`` (converted to ROS 2 messages as it plays); messages are published as CDR bytes,
unchanged, at their recorded log times scaled by ``-r/--rate``, with the QoS the recorder saw
offered (reliability, durability, history depth), or reliable with ``--reliable`` (a
best-effort camera's recording played best effort loses every frame over 512 KiB to a subscriber
on this host that receives through Fast DDS's shared memory, see ``sepfm_ros.ros.node.dds``; a
warning says so). ``--topics`` selects topics,
``--exclude-topics`` leaves some out, ``--remap FROM:=TO`` renames them (``--left L --right R`` /
``--image I`` are short for remapping recorded camera topics onto the node's ``/left/image_raw``,
``/right/image_raw`` / ``/image_raw``), ``--start-offset S`` skips the first S seconds,
``-l/--loop`` repeats (each pass publishes the recorded messages again, so header stamps jump back
to the bag's start, as with ``ros2 bag play --loop``), and ``--clock`` publishes ``/clock``
(rosgraph_msgs/Clock) with the bag's time so nodes with ``use_sim_time:=true`` follow it.
``--wait-for TOPIC`` waits until TOPIC has a subscriber before starting (useful when a node is
still starting up). A progress line runs on stderr; playing starts at once (message counts come
from the bag's metadata).

Topics whose message type has no Python package here (``/tf`` without ``tf2_msgs``, a custom
type) are skipped with one warning each, and the rest is played, as ``ros2 bag play`` does. Bad
input (missing bag, corrupt or truncated storage, unknown topic, nothing playable) gives a
message and exit code 1, before anything is published. Header stamps that repeat, go backwards or
leave gaps (an interval over ``GAP_FACTOR`` times the topic's median) are played as recorded, the
way a real camera would deliver them, and counted per topic in a warning after the first pass;
``--strict`` checks them before playing and refuses such bags instead (exit code 1).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from rclpy.signals import SignalHandlerOptions

from sepfm_ros.ros.bags.errors import BagError
from sepfm_ros.ros.bags.reader import BagReader
from sepfm_ros.ros.node.replayer import (
    Replayer,
    input_remaps,
    parse_remaps,
)
from sepfm_ros.ros.node.signals import install_stop_handlers, restore_handlers


def _parse(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        prog="sepfm_ros replay",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("bag", type=Path, help="bag to play: rosbag2 folder, .mcap, .db3 or ROS 1 .bag")
    p.add_argument("-r", "--rate", type=float, default=1.0, help="speed factor (default 1)")
    p.add_argument(
        "-l",
        "--loop",
        action="store_true",
        help="repeat until interrupted (header stamps jump back to the start at each pass)",
    )
    p.add_argument("--start-offset", type=float, default=0.0, metavar="S", help="skip S seconds")
    p.add_argument("--topics", nargs="+", default=[], metavar="TOPIC", help="topics to play")
    p.add_argument(
        "--exclude-topics", nargs="+", default=[], metavar="TOPIC", help="topics not to play"
    )
    p.add_argument("--remap", nargs="+", default=[], metavar="FROM:=TO", help="rename topics")
    p.add_argument(
        "--left",
        metavar="TOPIC",
        help="publish this recorded image topic as the node's left/image_raw (with --right)",
    )
    p.add_argument(
        "--right",
        metavar="TOPIC",
        help="publish this recorded image topic as the node's right/image_raw (with --left)",
    )
    p.add_argument(
        "--image", metavar="TOPIC", help="publish this recorded image topic as the node's image_raw"
    )
    p.add_argument(
        "--reliable",
        action="store_true",
        help="publish every topic reliable, whatever QoS the bag recorded",
    )
    p.add_argument("--clock", action="store_true", help="publish /clock with the bag's time")
    p.add_argument("--clock-hz", type=float, default=100.0, help="/clock rate (default 100)")
    p.add_argument(
        "--wait-for",
        nargs="+",
        default=[],
        metavar="TOPIC",
        help="wait for a subscriber on these (published) topics before playing",
    )
    p.add_argument("--wait-timeout", type=float, default=30.0, help="seconds (default 30)")
    p.add_argument("--quiet", action="store_true", help="no progress line")
    p.add_argument(
        "--strict",
        action="store_true",
        help="refuse a bag whose header stamps repeat or go backwards (default: warn and play)",
    )
    return p.parse_args(argv)


def main(argv: list[str]) -> int:
    import rclpy

    from sepfm_ros.ros.node.spin import own_arguments

    # Own arguments come before --ros-args: rcl's remove_ros_args would also take our
    # "--remap FROM:=TO" values for (deprecated-syntax) ROS remap rules.
    split = argv.index("--ros-args") if "--ros-args" in argv else len(argv)
    args = _parse(argv[:split])
    ros_argv = argv[split:]
    own_arguments("sepfm_ros replay", "replay", ros_argv)  # exits 2 when rcl cannot parse them
    try:
        remap = parse_remaps(args.remap)
        with BagReader(args.bag) as reader:  # fail fast on a bad bag, before DDS starts
            remap.update(input_remaps(reader, args.left, args.right, args.image))
    except BagError as err:
        print(f"sepfm_ros replay: error: {err}", file=sys.stderr)
        return 1
    # SIGINT is Python's KeyboardInterrupt here, not rclpy's handler: rclpy's shuts the context
    # down at once, and a publish in flight then fails with "context is invalid" (a traceback)
    # before the interrupt reaches the loop
    rclpy.init(args=["replay", *ros_argv], signal_handler_options=SignalHandlerOptions.NO)
    previous = install_stop_handlers()
    node = rclpy.create_node("sepfm_replay")
    replayer = None
    try:
        replayer = Replayer(
            node,
            args.bag,
            args.topics,
            remap,
            args.rate,
            args.start_offset,
            args.loop,
            args.clock,
            args.clock_hz,
            strict=args.strict,
            exclude=args.exclude_topics,
            reliable=args.reliable,
        )
        for line in replayer.start_warnings():
            print(f"sepfm_ros replay: {line}", file=sys.stderr, flush=True)
        if args.wait_for:
            replayer.wait_for_subscribers(args.wait_for, args.wait_timeout)
        n = replayer.run(progress=not args.quiet)
        for line in replayer.stamp_warnings():
            print(f"sepfm_ros replay: {line}", file=sys.stderr, flush=True)
        print(f"replayed {n} messages from {args.bag}", file=sys.stderr)
        return 0
    except BagError as err:
        print(f"sepfm_ros replay: error: {err}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        if replayer is not None:
            replayer.stop()
        print("sepfm_ros replay: interrupted", file=sys.stderr)
        return 130
    finally:
        restore_handlers(previous)
        if replayer is not None:
            replayer.close()
        node.destroy_node()
        rclpy.try_shutdown()
