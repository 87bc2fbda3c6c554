"""Launch one sepfm node per stereo rig of a robot, each in its own namespace.

    ros2 launch sepfm_ros sepfm_rigs_launch.py rigs:=front,rear
    ros2 launch sepfm_ros sepfm_rigs_launch.py rigs:=front,left,right image_transport:=compressed

Each rig NAME gets a node ``/NAME/sepfm`` (the config/sepfm.yaml parameters, stereo mode) whose
inputs are the rig's ``/NAME/left/image_raw`` and ``/NAME/right/image_raw`` with their
``camera_info`` beside them, and whose outputs and calibration check are under ``/NAME/sepfm/``.
Arguments: rigs (comma-separated namespaces), image_transport (raw|compressed), params_file,
use_sim_time, autostart (the nodes are lifecycle nodes, launch_ros ``LifecycleNode``s, that
configure and activate themselves unless autostart:=false). How many rigs a host answers
completely is measured in docs/benchmarks.md (``benchmarks/bench_rigs.py``).
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import LifecycleNode

from launch import LaunchDescription


def rig_names(text: str) -> list[str]:
    """The rig namespaces of a ``rigs`` argument ("front, rear" -> ["front", "rear"])."""
    names = [n.strip().strip("/") for n in text.split(",")]
    names = [n for n in names if n]
    if not names:
        raise ValueError("rigs:= names no rig (give comma-separated namespaces, e.g. front,rear)")
    if len(set(names)) != len(names):
        raise ValueError(f"rigs:= names a rig twice: {text}")
    return names


def _nodes(context) -> list[LifecycleNode]:
    names = rig_names(LaunchConfiguration("rigs").perform(context))
    sim_time = LaunchConfiguration("use_sim_time").perform(context).lower() == "true"
    autostart = LaunchConfiguration("autostart").perform(context).lower() == "true"
    return [
        LifecycleNode(
            package="sepfm_ros",
            executable="node",
            name="sepfm",
            namespace=name,
            output="screen",
            parameters=[
                LaunchConfiguration("params_file"),
                {
                    "mode": "stereo",
                    "image_transport": LaunchConfiguration("image_transport"),
                    "use_sim_time": sim_time,
                    "autostart": autostart,
                },
            ],
        )
        for name in names
    ]


def generate_launch_description() -> LaunchDescription:
    default_params = os.path.join(get_package_share_directory("sepfm_ros"), "config", "sepfm.yaml")
    args = {
        "rigs": ("stereo", "comma-separated rig namespaces, one node each"),
        "image_transport": ("raw", "raw or compressed (the nodes subscribe to <topic>/compressed)"),
        "params_file": (default_params, "node parameters (YAML), shared by every rig"),
        "use_sim_time": ("false", "true: stamps and /diagnostics on /clock time (bag replay)"),
        "autostart": ("true", "configure and activate at start (false: a lifecycle manager does)"),
    }
    declared = [
        DeclareLaunchArgument(k, default_value=v, description=d) for k, (v, d) in args.items()
    ]
    return LaunchDescription([*declared, OpaqueFunction(function=_nodes)])
