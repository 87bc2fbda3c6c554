"""A small renderer of textured planar scenes with known cameras (exact ground-truth F).

No ROS here: :mod:`sepfm_ros.synthetic.scene` renders planes, :mod:`sepfm_ros.synthetic.sequences`
builds stereo and motion sequences from them. ``scripts/make_bundled_bags.py`` turns the sequences
into the bags under ``bags/``.
"""

from sepfm_ros.synthetic.scene import Camera, Plane, Scene, make_texture, render
from sepfm_ros.synthetic.sequences import Frame, motion_sequence, stereo_sequence

__all__ = [
    "Camera",
    "Frame",
    "Plane",
    "Scene",
    "make_texture",
    "motion_sequence",
    "render",
    "stereo_sequence",
]
