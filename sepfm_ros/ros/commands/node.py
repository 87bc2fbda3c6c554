"""``sepfm_ros node``: the process around :class:`~sepfm_ros.ros.node.sepfm.SepfmNode`.

Process-wide settings first (malloc thresholds, the DDS settings, one thread per native pool),
then the estimator's kernels (compiled once after an install, loaded from the cache afterwards) on
a thread, while the lifecycle node is already in the graph on a single-threaded executor until
SIGINT or SIGTERM (``autostart`` configures and activates it once the kernels are ready).
"""

from __future__ import annotations

import os

from sepfm_ros.ros.node.dds import configure_dds
from sepfm_ros.ros.node.lifecycle import KernelWarmUp
from sepfm_ros.ros.node.memory import configure_malloc
from sepfm_ros.ros.node.sepfm import SepfmNode
from sepfm_ros.ros.node.spin import limit_thread_pools, parse_command_line, run_node
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
        "A lifecycle node (lifecycle_msgs services ~/change_state, ~/get_state, ...): it is in",
        "the graph at once, reporting 'warming up' on /diagnostics while the estimator's kernels",
        "compile or load; then it configures and activates itself (autostart:=false: it waits",
        "for a lifecycle manager). Deactivated, it holds no input and publishes nothing.",
        "",
        "On demand: the node subscribes to its images (and camera_info) only while ~/estimate,",
        "~/matches, the pose outputs or ~/debug_image have a subscriber (/diagnostics does not",
        "count), within a second of the first one, and answers fresh pairs from then on; idle,",
        "/diagnostics says OK 'idle: no subscribers' and the stall checks are off. always_on:=true",
        "keeps it processing for monitoring; it defaults to true for calibrated stereo (mode",
        "stereo with use_camera_info), where the calibration check is the point.",
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
    warm = KernelWarmUp()

    def make_node() -> SepfmNode:
        node = SepfmNode(dds=dds, warm=warm)
        # after rclpy.init (its SIGINT/SIGTERM handlers stop a compile too) and after the node
        # is in the graph (the warm-up holds the GIL for much of its time): compile (fresh
        # install) or load the estimator's kernels on a thread of their own; the node answers
        # its lifecycle services meanwhile, and configure waits for them
        warm.start()
        node.get_logger().info(
            f"memory: malloc thresholds {'fixed' if malloc_fixed else 'left (not glibc)'}, "
            + ("DDS subscriptions with DYNAMIC history" if dds.profiles else "DDS config left")
            + f"; image input over {dds.describe()}"
        )
        return node

    code = run_node("sepfm_ros node", "sepfm", argv, make_node, SepfmNode.shutdown)
    if warm.running:  # stopped while the kernels compile: that thread cannot be joined
        print("sepfm_ros node: interrupted while preparing the estimator", flush=True)
        os._exit(code)
    return code
