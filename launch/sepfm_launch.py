"""Launch the sepfm node with the installed config/sepfm.yaml.

    ros2 launch sepfm_ros sepfm_launch.py mode:=motion image:=/camera/image_raw
    ros2 launch sepfm_ros sepfm_launch.py left:=/stereo/left/image_raw \
        right:=/stereo/right/image_raw
    ros2 launch sepfm_ros sepfm_launch.py namespace:=robot1 image_transport:=compressed \
        use_sim_time:=true

Arguments: mode (stereo|motion), image_transport (raw|compressed), params_file, namespace,
use_sim_time, and the input topics left, right (stereo) and image (motion). The topics are base
image topics: with image_transport:=compressed the node adds /compressed after the remap, as
image_transport does.

The node is a lifecycle node (launch_ros ``LifecycleNode``): it configures and activates itself
(``autostart``, default true); with ``autostart:=false`` a lifecycle manager drives it.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import LifecycleNode
from launch_ros.parameter_descriptions import ParameterValue

from launch import LaunchDescription


def generate_launch_description() -> LaunchDescription:
    default_params = os.path.join(get_package_share_directory("sepfm_ros"), "config", "sepfm.yaml")
    args = {
        "mode": ("stereo", "stereo or motion"),
        "image_transport": ("raw", "raw or compressed (the node subscribes to <topic>/compressed)"),
        "params_file": (default_params, "node parameters (YAML)"),
        "namespace": ("", "namespace of the node (its relative input topics follow it)"),
        "use_sim_time": ("false", "true: stamps and /diagnostics on /clock time (bag replay)"),
        "left": ("left/image_raw", "stereo: left image topic"),
        "right": ("right/image_raw", "stereo: right image topic"),
        "image": ("image_raw", "motion: image topic"),
        "autostart": ("true", "configure and activate at start (false: a lifecycle manager does)"),
    }
    node = LifecycleNode(
        package="sepfm_ros",
        executable="node",
        name="sepfm",
        namespace=LaunchConfiguration("namespace"),
        output="screen",
        parameters=[
            LaunchConfiguration("params_file"),
            {
                "mode": LaunchConfiguration("mode"),
                "image_transport": LaunchConfiguration("image_transport"),
                "use_sim_time": ParameterValue(
                    LaunchConfiguration("use_sim_time"), value_type=bool
                ),
                "autostart": ParameterValue(LaunchConfiguration("autostart"), value_type=bool),
            },
        ],
        remappings=[
            ("left/image_raw", LaunchConfiguration("left")),
            ("right/image_raw", LaunchConfiguration("right")),
            ("image_raw", LaunchConfiguration("image")),
        ],
    )
    declared = [
        DeclareLaunchArgument(k, default_value=v, description=d) for k, (v, d) in args.items()
    ]
    return LaunchDescription([*declared, node])
