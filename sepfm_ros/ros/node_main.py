"""``sepfm_ros node``: the process around :class:`~sepfm_ros.ros.node.SepfmNode`.

Process-wide settings first (malloc thresholds, the DDS settings, one thread per native pool),
then the estimator's kernels (compiled once after an install, loaded from the cache afterwards),
then the node on a single-threaded executor until SIGINT or SIGTERM.
"""

from __future__ import annotations

import os
import threading

import cv2
from threadpoolctl import threadpool_limits

from sepfm_ros.pipeline.compiled import warm_up
from sepfm_ros.ros.dds import configure_dds
from sepfm_ros.ros.memory import configure_malloc
from sepfm_ros.ros.node import SepfmNode
from sepfm_ros.ros.node_process import parse_command_line, run_node
from sepfm_ros.ros.parameters import parameters_help
from sepfm_ros.ros.signals import install_stop_handlers, restore_handlers


def limit_thread_pools(threads: int = 1) -> None:
    """Run OpenCV's and the BLAS's internal parallel loops on ``threads`` threads (process-wide).

    The node already runs two worker threads on machines with few cores; native pools on top of
    them only oversubscribe the cores (OpenBLAS workers also busy-wait after each call). Results
    do not change: only how the work is scheduled.
    """
    cv2.setNumThreads(int(threads))
    threadpool_limits(limits=int(threads), user_api="blas")


def _usage() -> str:
    lines = [
        "The sepfm node: subscribes to left/image_raw + right/image_raw (mode:=stereo) or",
        "image_raw (mode:=motion), publishes ~/estimate (sepfm_msgs/TwoViewEstimate, one per",
        "pair), ~/matches (sepfm_msgs/MatchArray), /diagnostics, ~/debug_image and, with",
        "camera_info, ~/relative_transform and ~/calibration_check.",
        "",
        "parameters:",
        parameters_help(),
    ]
    return "\n".join(lines)


def warm_up_interruptibly() -> float | None:
    """:func:`warm_up` in a thread, so SIGINT / SIGTERM stop the node while kernels compile.

    numba compiles on: a KeyboardInterrupt raised in the compiling thread is lost. Returns the
    seconds spent, or None when interrupted (the thread is left to the process's exit).

    Both signals get a handler here (:func:`install_stop_handlers`; rclpy's handlers,
    installed later, take SIGINT whatever the process inherited).
    """
    done: dict[str, float] = {}
    thread = threading.Thread(
        target=lambda: done.update(s=warm_up()), name="kernel-warm-up", daemon=True
    )
    previous = install_stop_handlers()
    try:
        thread.start()
        while thread.is_alive():
            thread.join(0.1)
    except KeyboardInterrupt:
        return None
    finally:
        restore_handlers(previous)
    return done.get("s", 0.0)


def main(argv: list[str]) -> int:
    """Run the node until SIGINT/SIGTERM; returns the process exit code."""
    parse_command_line(
        "sepfm_ros node",
        "sepfm",
        argv,
        "%(prog)s [--ros-args -p NAME:=VALUE ... --params-file FILE -r FROM:=TO ...]",
        _usage(),
    )
    # before any image flows and before rclpy creates the DDS participant (see ros/memory.py)
    malloc_fixed = configure_malloc()
    dds = configure_dds()
    limit_thread_pools(1)
    # compile (fresh install) or load the estimator's kernels before the first frame arrives
    warm_s = warm_up_interruptibly()
    if warm_s is None:
        print("sepfm_ros node: interrupted while preparing the estimator", flush=True)
        os._exit(0)  # the compiling thread cannot be joined; nothing is open yet

    def make_node() -> SepfmNode:
        node = SepfmNode(dds=dds)
        node.get_logger().info(f"estimator kernels ready in {warm_s:.1f} s")
        node.get_logger().info(
            f"memory: malloc thresholds {'fixed' if malloc_fixed else 'left (not glibc)'}, "
            + ("DDS subscriptions with DYNAMIC history" if dds.profiles else "DDS config left")
            + f"; image input over {dds.describe()}"
        )
        return node

    return run_node("sepfm_ros node", "sepfm", argv, make_node, SepfmNode.shutdown)
