"""The relative pose and stereo geometry of calibrated cameras, by its documented public name:
every name of :mod:`sepfm_ros.geometry.calibrated.pose` (where the code lives)."""

from sepfm_ros.geometry.calibrated.pose import (
    MIN_POSE_POINTS,
    RelativePose,
    direction_error_deg,
    essential_from_fundamental,
    fundamental_from_pose,
    in_front_mask,
    normalized_points,
    pose_from_projections,
    pose_of_b_in_a,
    rectified_offset,
    refine_pose,
    relative_pose,
    rotation_angle_deg,
    rotation_error_deg,
    stereo_baseline,
    stereo_fundamental,
    stereo_pose,
)

__all__ = [
    "MIN_POSE_POINTS",
    "RelativePose",
    "direction_error_deg",
    "essential_from_fundamental",
    "fundamental_from_pose",
    "in_front_mask",
    "normalized_points",
    "pose_from_projections",
    "pose_of_b_in_a",
    "rectified_offset",
    "refine_pose",
    "relative_pose",
    "rotation_angle_deg",
    "rotation_error_deg",
    "stereo_baseline",
    "stereo_fundamental",
    "stereo_pose",
]
