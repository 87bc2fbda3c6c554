"""``sepfm_ros node``: the process around :class:`~sepfm_ros.ros.node.sepfm.SepfmNode`.

Process-wide settings first (malloc thresholds, the DDS settings, one thread per native pool),
then the estimator's kernels (compiled once after an install, loaded from the cache afterwards),
then the node on a single-threaded executor until SIGINT or SIGTERM.
"""

from __future__ import annotations

import os

from sepfm_ros.ros.node.dds import configure_dds
from sepfm_ros.ros.node.memory import configure_malloc
from sepfm_ros.ros.node.sepfm import SepfmNode
from sepfm_ros.ros.node.spin import (
    limit_thread_pools,
    parse_command_line,
    run_node,
    warm_up_interruptibly,
)
from sepfm_ros.ros.session.parameters import parameters_help, renamed_help


def _usage() -> str:
    lines = [
        "The sepfm node: subscribes to left/image_raw + right/image_raw (mode:=stereo) or",
        "image_raw (mode:=motion), publishes ~/estimate (sepfm_msgs/TwoViewEstimate, one per",
        "pair), ~/matches (sepfm_msgs/MatchArray), /diagnostics, ~/debug_image (and its JPEG",
        "~/debug_image/compressed) and, with camera_info, the pose: ~/relative_transform and",
        "~/relative_pose (stereo: camera b in camera a's optical frame, with covariance) or",
        "~/angular_velocity and ~/translation_direction (motion: rotation rate with covariance,",
        "unit direction), and ~/calibration_check (diagnostic_msgs/DiagnosticArray stamped with",
        "the pair's header). /diagnostics names its statuses '<node FQN>: node' and",
        "'<node FQN>: calibration' (e.g. '/front/sepfm: node'), every diagnostic_updater.period",
        "seconds.",
        "image_transport:=compressed subscribes to <topic>/compressed, as image_transport's",
        "TransportHints. camera_info (beside each image topic) is matched to each image by stamp",
        "(exact, else nearest within sync_slop_s); images without one, and frames missing from",
        "a camera's stamp sequence, are counted in /diagnostics.",
        "",
        "parameters:",
        parameters_help(),
        renamed_help(),
    ]
    return "\n".join(lines)


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
