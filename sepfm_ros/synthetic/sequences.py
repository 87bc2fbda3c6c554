"""Stereo and motion sequences of one synthetic scene, with exact cameras.

The scene is a small "street": a textured back wall, two side walls, a floor and a few
free-standing boards at odd angles, all rich in straight edges. Every random choice takes a seed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sepfm_ros.geometry import fundamental_from_cameras
from sepfm_ros.synthetic.scene import (
    Camera,
    Scene,
    intrinsics,
    look_at,
    make_texture,
    plane_at,
    render,
)

DEFAULT_SIZE = (480, 360)


@dataclass(frozen=True)
class Frame:
    """One time step: one image (motion) or a left/right pair (stereo), with their cameras.

    Attributes:
        images: (h, w) uint8 or (h, w, 3) uint8 BGR images, one per camera.
        cameras: the camera of each image.
    """

    images: tuple[np.ndarray, ...]
    cameras: tuple[Camera, ...]


def street_scene(seed: int = 0, color: bool = False) -> Scene:
    """The bundled scene: walls, floor and boards with procedural textures (seeded)."""
    rng = np.random.default_rng(seed)

    def tex(w: int = 512, h: int = 384):
        return make_texture(rng, (w, h), color=color)

    planes = [
        plane_at((0.0, -1.0, 14.0), (1, 0, 0), (0, 1, 0), 18.0, tex(640, 320)),  # back wall
        plane_at((-3.2, -0.8, 8.0), (0, 0, 1), (0, 1, 0), 11.0, tex(640, 320)),  # left wall
        plane_at((3.2, -0.8, 8.0), (0, 0, -1), (0, 1, 0), 11.0, tex(640, 320)),  # right wall
        plane_at((0.0, 1.6, 8.5), (1, 0, 0), (0, 0, -1), 6.4, tex(512, 640)),  # floor
        plane_at((-1.1, 0.2, 7.0), (1, 0, 0.6), (0, 1, 0), 1.6, tex(320, 384)),  # board
        plane_at((1.3, -0.2, 9.5), (1, 0, -0.8), (0.1, 1, 0), 2.0, tex(384, 320)),  # board
        plane_at((0.2, -1.6, 11.0), (1, 0.2, 0), (0, 1, 0.3), 2.4, tex(384, 256)),  # sign
    ]
    return Scene(tuple(planes), background=int(rng.integers(20, 60)))


def stereo_sequence(
    n_frames: int = 12,
    size: tuple[int, int] = DEFAULT_SIZE,
    baseline_m: float = 0.35,
    toe_in_deg: float = 2.0,
    speed_m: float = 0.15,
    seed: int = 0,
    color: bool = False,
    right_size: tuple[int, int] | None = None,
) -> list[Frame]:
    """A stereo rig driving forward through :func:`street_scene`.

    The rig is slightly converged (``toe_in_deg`` per camera) and the right camera a little
    lower, so F is a general rank-2 matrix rather than the rectified one. ``speed_m`` metres per
    frame along +z with a gentle sway. ``right_size``: the right camera's (width, height) when
    the rig pairs two different cameras (same 70 degree field of view), else ``size``.
    """
    scene = street_scene(seed, color)
    sizes = {"left": size, "right": right_size or size}
    Ks = {side: intrinsics(sz, 70.0) for side, sz in sizes.items()}
    frames = []
    for k in range(n_frames):
        c = np.array([0.25 * np.sin(0.4 * k), -0.05 * np.cos(0.3 * k), speed_m * k])
        target = c + np.array([0.05 * np.sin(0.25 * k), 0.0, 10.0])
        R, _ = look_at(c, target)
        cams = []
        for side, sign in (("left", -1.0), ("right", 1.0)):
            offset = np.array([sign * baseline_m / 2, 0.02 if side == "right" else 0.0, 0.0])
            cw = c + R.T @ offset
            yaw = np.radians(-sign * toe_in_deg)
            Ry = np.array(
                [[np.cos(yaw), 0, np.sin(yaw)], [0, 1, 0], [-np.sin(yaw), 0, np.cos(yaw)]]
            )
            Rc = Ry @ R
            cams.append(Camera(Ks[side], Rc, -Rc @ cw, sizes[side]))
        images = tuple(render(scene, cam, color=color) for cam in cams)
        frames.append(Frame(images, tuple(cams)))
    return frames


def motion_sequence(
    n_frames: int = 13,
    size: tuple[int, int] = DEFAULT_SIZE,
    step_deg: float = 1.5,
    seed: int = 0,
    color: bool = False,
) -> list[Frame]:
    """One camera moving sideways and forward while panning across :func:`street_scene`.

    Consecutive frames differ by about ``step_deg`` degrees of pan and 0.12 m of travel.
    """
    scene = street_scene(seed, color)
    K = intrinsics(size, 65.0)
    frames = []
    for k in range(n_frames):
        c = np.array([-1.2 + 0.12 * k, -0.2 + 0.02 * np.sin(0.5 * k), 0.5 + 0.08 * k])
        ang = np.radians(-8.0 + step_deg * k)
        target = c + np.array([np.sin(ang), 0.05, np.cos(ang)]) * 10.0
        R, t = look_at(c, target)
        cam = Camera(K, R, t, size)
        frames.append(Frame((render(scene, cam, color=color),), (cam,)))
    return frames


def pair_fundamental(cam_a: Camera, cam_b: Camera) -> np.ndarray:
    """Exact (3, 3) F with ``x_b^T F x_a = 0`` (unit norm, largest entry positive)."""
    return fundamental_from_cameras(cam_a.P, cam_b.P)
