"""Render textured planes seen by pinhole cameras, with OpenCV's warpPerspective.

Conventions: world points X (3,) in metres; a camera is ``P = K [R | t]`` (3x4) mapping
homogeneous world points to pixels with the origin at the centre of the top-left pixel (OpenCV
keypoint convention), so the ground-truth F of two cameras is exact in the same pixels a feature
detector reports. A plane is a textured rectangle ``X(s, t) = origin + s * u + t * v`` with (s, t)
the texture's pixel coordinates (same centre convention), so each plane maps to the image by the
homography ``H = P [u v origin; 0 0 1]``. Planes are drawn far to near (painter's algorithm); the
scenes of :mod:`sepfm_ros.synthetic.sequences` keep them in front of every camera.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class Camera:
    """A pinhole camera.

    Attributes:
        K: (3, 3) intrinsics in pixels.
        R: (3, 3) world-to-camera rotation.
        t: (3,) world-to-camera translation (metres), so ``x_cam = R X + t``.
        size: (width, height) in pixels.
    """

    K: np.ndarray
    R: np.ndarray
    t: np.ndarray
    size: tuple[int, int]

    @property
    def P(self) -> np.ndarray:
        """(3, 4) projection matrix ``K [R | t]``."""
        return self.K @ np.hstack([self.R, self.t.reshape(3, 1)])

    @property
    def center(self) -> np.ndarray:
        """(3,) camera centre in world coordinates."""
        return -self.R.T @ self.t


@dataclass(frozen=True)
class Plane:
    """A textured rectangle ``X(s, t) = origin + s * u + t * v``, (s, t) texture pixels.

    Attributes:
        origin: (3,) world position of texture pixel (0, 0).
        u: (3,) world step per texture pixel along the texture's x axis.
        v: (3,) world step per texture pixel along the texture's y axis.
        texture: (h, w) uint8 or (h, w, 3) uint8 BGR image.
    """

    origin: np.ndarray
    u: np.ndarray
    v: np.ndarray
    texture: np.ndarray

    def corners(self) -> np.ndarray:
        """(4, 3) world corners of the rectangle."""
        h, w = self.texture.shape[:2]
        st = np.array([[0, 0], [w - 1, 0], [w - 1, h - 1], [0, h - 1]], dtype=np.float64)
        return self.origin + st[:, :1] * self.u + st[:, 1:] * self.v


@dataclass(frozen=True)
class Scene:
    """Planes plus a background grey level (0..255)."""

    planes: tuple[Plane, ...]
    background: int = 40


def plane_at(center, right, down, width_m: float, texture: np.ndarray) -> Plane:
    """A plane of ``width_m`` metres centred at ``center``, texture x along ``right``, y ``down``.

    ``right`` and ``down`` are (3,) directions (normalised here); the height follows the texture's
    aspect ratio.
    """
    h, w = texture.shape[:2]
    right = np.asarray(right, dtype=np.float64)
    down = np.asarray(down, dtype=np.float64)
    step = width_m / (w - 1)
    u = right / np.linalg.norm(right) * step
    v = down / np.linalg.norm(down) * step
    origin = np.asarray(center, dtype=np.float64) - u * (w - 1) / 2 - v * (h - 1) / 2
    return Plane(origin, u, v, texture)


def make_texture(
    rng: np.random.Generator, size: tuple[int, int] = (512, 384), color: bool = False
) -> np.ndarray:
    """A procedural texture rich in straight edges and corners.

    Random filled rectangles and polygons (some rotated), thick straight lines and a little
    per-pixel noise on a mid-grey base. Returns (h, w) uint8, or (h, w, 3) uint8 BGR if ``color``.
    """
    w, h = size
    ch = 3 if color else 1
    img = np.empty((h, w, ch), np.uint8)
    img[:] = rng.integers(70, 190, ch).astype(np.uint8)

    def colour() -> tuple[int, ...]:
        return tuple(int(c) for c in rng.integers(0, 256, ch))

    for _ in range(int(rng.integers(25, 40))):
        cx, cy = rng.uniform(0, w), rng.uniform(0, h)
        a, b = rng.uniform(8, w / 5), rng.uniform(8, h / 5)
        ang = rng.uniform(0, 180) if rng.random() < 0.5 else 0.0
        box = cv2.boxPoints(((cx, cy), (a, b), ang)).astype(np.int32)
        cv2.fillConvexPoly(img, box, colour(), lineType=cv2.LINE_AA)
    for _ in range(int(rng.integers(10, 20))):
        p = rng.uniform(0, 1, 2) * (w, h)
        q = rng.uniform(0, 1, 2) * (w, h)
        cv2.line(
            img,
            tuple(int(x) for x in p),
            tuple(int(x) for x in q),
            colour(),
            int(rng.integers(2, 6)),
            cv2.LINE_AA,
        )
    noise = rng.normal(0.0, 4.0, img.shape)
    img = np.clip(img.astype(np.float64) + noise, 0, 255).astype(np.uint8)
    return img if color else img[:, :, 0]


def look_at(center, target, up=(0.0, -1.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """World-to-camera (R, t) of a camera at ``center`` looking at ``target``.

    Camera axes: x right, y down, z forward (OpenCV); ``up`` is the world's up direction.
    """
    c = np.asarray(center, dtype=np.float64)
    z = np.asarray(target, dtype=np.float64) - c
    z /= np.linalg.norm(z)
    x = np.cross(z, -np.asarray(up, dtype=np.float64))
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    return R, -R @ c


def intrinsics(size: tuple[int, int], fov_x_deg: float) -> np.ndarray:
    """(3, 3) K with square pixels, principal point at the image centre."""
    w, h = size
    f = (w / 2) / np.tan(np.radians(fov_x_deg) / 2)
    return np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1.0]])


def render(scene: Scene, camera: Camera, supersample: int = 2, color: bool = False) -> np.ndarray:
    """Render ``scene`` seen by ``camera``: (h, w) uint8, or (h, w, 3) BGR if ``color``.

    Rendered at ``supersample`` times the resolution and reduced with area averaging (less
    aliasing); the supersampled camera is ``S K`` with ``S`` mapping output pixel centres to the
    centres of the pixel blocks, so the projection of every world point is exact in the output.

    Raises:
        ValueError: a plane corner lies behind the camera (the homography would fold).
    """
    w, h = camera.size
    s = int(supersample)
    S = np.array([[s, 0, (s - 1) / 2], [0, s, (s - 1) / 2], [0, 0, 1.0]])
    P = S @ camera.P
    ch = 3 if color else 1
    canvas = np.full((h * s, w * s, ch), scene.background, np.float32)

    def depth(plane: Plane) -> float:
        return float(np.mean((camera.R @ plane.corners().T + camera.t[:, None])[2]))

    for plane in sorted(scene.planes, key=depth, reverse=True):
        z = (camera.R @ plane.corners().T + camera.t[:, None])[2]
        if np.any(z <= 1e-3):
            raise ValueError("a plane corner lies behind the camera")
        H = P @ np.vstack([np.column_stack([plane.u, plane.v, plane.origin]), [0.0, 0.0, 1.0]])
        tex = plane.texture
        if tex.ndim == 2 and color:
            tex = cv2.cvtColor(tex, cv2.COLOR_GRAY2BGR)
        elif tex.ndim == 3 and not color:
            tex = cv2.cvtColor(tex, cv2.COLOR_BGR2GRAY)
        tex = tex.astype(np.float32).reshape(tex.shape[0], tex.shape[1], ch)
        size = (w * s, h * s)
        warped = cv2.warpPerspective(tex, H, size, flags=cv2.INTER_LINEAR)
        mask = cv2.warpPerspective(
            np.ones(tex.shape[:2], np.float32), H, size, flags=cv2.INTER_LINEAR
        )
        warped = warped.reshape(h * s, w * s, ch)
        mask = mask[:, :, None]
        canvas = canvas * (1.0 - mask) + warped
    out = cv2.resize(canvas, (w, h), interpolation=cv2.INTER_AREA).reshape(h, w, ch)
    out = np.clip(np.rint(out), 0, 255).astype(np.uint8)
    return out if color else out[:, :, 0]
