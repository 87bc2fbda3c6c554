"""``sepfm_ros rectify``: rectified stereo images for a rig without ``camera_info``.

A consumer of the sepfm node's typed outputs. It subscribes to

- ``left/image_raw`` and ``right/image_raw`` (the sepfm node's input topics, the same remaps,
  ``image_transport`` and encodings; paired by stamp as the sepfm node pairs them), and
- ``sepfm/estimate`` (``sepfm_msgs/TwoViewEstimate``) and ``sepfm/matches``
  (``sepfm_msgs/MatchArray``): the outputs of a sepfm node named ``sepfm`` in the same
  namespace; remap them for another name. An estimate and its matches are joined by header
  stamp.

and publishes ``left/image_rect`` and ``right/image_rect`` (``sensor_msgs/Image``, ``encoding``
mono8 or bgr8, each with its input image's header) and its health on ``/diagnostics``.

Each estimate with status ok, F in image pixels and its inlier matches gives two homographies
(:func:`sepfm_ros.pipeline.rectification.rectify_uncalibrated`; an estimate whose inliers keep
a median vertical disparity above ``max_vertical_px`` after them is refused). Every image pair
is rectified with the homographies of the latest good estimate received before it. They are
**held**, not smoothed: a bad estimate (not ok, too few inliers, an epipole inside the image,
a framed image covering too little of the output, ...) leaves the previous homographies in
use, and the next good one replaces them. Homographies of two estimates are not averaged
because each pair (H_a, H_b) is consistent only with itself (Hartley's H_b fixes a rotation
about the baseline, H_a a shear fitted to that estimate's matches): the mean of two solutions
need not rectify. A rigid rig's F does not change, so the latest good one serves as well as a
mean, and a knocked camera takes effect at its next good estimate.

Bad input never stops the node: undecodable images, an image pair of another size than the
estimate's, refused estimates and estimates whose matches never arrive are counted by kind in
``/diagnostics`` and logged at most every 10 s per kind; pairs before the first good estimate
are counted as ``waiting``.
"""

from __future__ import annotations

from sepfm_ros.ros.node.dds import configure_dds
from sepfm_ros.ros.node.rectify import (
    NODE_NAME,
    PARAMS,
    RectifyNode,
)
from sepfm_ros.ros.node.spin import parse_command_line, run_node
from sepfm_ros.ros.session.parameters import parameters_help, renamed_help


def _usage() -> str:
    return "\n".join(
        [
            __doc__.split("\n\n")[0],
            "",
            "Subscribes to left/image_raw + right/image_raw and sepfm/estimate + sepfm/matches;",
            "publishes left/image_rect, right/image_rect and /diagnostics (status",
            "'<node FQN>: rectify', every diagnostic_updater.period seconds).",
            "",
            "A lifecycle node (lifecycle_msgs services ~/change_state, ~/get_state, ...): it",
            "configures and activates itself unless autostart:=false; configure creates its",
            "publishers, activate its subscriptions; deactivated it publishes nothing.",
            "",
            "parameters (read-only):",
            parameters_help(PARAMS),
            renamed_help(),
        ]
    )


def main(argv: list[str]) -> int:
    """Run the rectifier until SIGINT/SIGTERM; returns the process exit code."""
    prog = "sepfm_ros rectify"
    usage = "%(prog)s [--ros-args -p NAME:=VALUE ... -r FROM:=TO ...]"
    parse_command_line(prog, NODE_NAME, argv, usage, _usage())
    dds = configure_dds()
    return run_node(prog, NODE_NAME, argv, lambda: RectifyNode(dds=dds))
