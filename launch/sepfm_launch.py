"""Launch the sepfm node with the installed config/sepfm.yaml.

    ros2 launch sepfm_ros sepfm_launch.py mode:=motion image:=/camera/image_raw
    ros2 launch sepfm_ros sepfm_launch.py left:=/stereo/left right:=/stereo/right

Arguments: mode (stereo|motion), transport (raw|compressed), params_file, and the input topics
left, right (stereo) and image (motion).
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from launch import LaunchDescription


def generate_launch_description() -> LaunchDescription:
    default_params = os.path.join(get_package_share_directory("sepfm_ros"), "config", "sepfm.yaml")
    args = {
        "mode": ("stereo", "stereo or motion"),
        "transport": ("raw", "raw or compressed"),
        "params_file": (default_params, "node parameters (YAML)"),
        "left": ("left/image_raw", "stereo: left image topic"),
        "right": ("right/image_raw", "stereo: right image topic"),
        "image": ("image_raw", "motion: image topic"),
    }
    node = Node(
        package="sepfm_ros",
        executable="node",
        name="sepfm",
        output="screen",
        parameters=[
            LaunchConfiguration("params_file"),
            {"mode": LaunchConfiguration("mode"), "transport": LaunchConfiguration("transport")},
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
