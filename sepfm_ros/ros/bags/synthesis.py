"""Bags built from image files, the shared data or synthetic scenes (``make_bag``'s library).

Images go out as ``sensor_msgs/Image`` (mono8, bgr8) or ``CompressedImage``, with camera_info
and ``/ground_truth/fundamental`` where the source has them.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from rclpy.serialization import serialize_message
from std_msgs.msg import Header

from sepfm_ros.geometry import fundamental_from_cameras
from sepfm_ros.ros.bags.errors import BagError
from sepfm_ros.ros.bags.types import COMPRESSED_IMAGE, GROUND_TRUTH_TOPIC, IMAGE
from sepfm_ros.ros.bags.writer import BagWriter, check_output_path
from sepfm_ros.ros.msgs.fundamental import (
    fundamental_to_image,
)
from sepfm_ros.ros.msgs.headers import camera_info_topic
from sepfm_ros.ros.msgs.image_conversion import numpy_to_compressed, numpy_to_image

ENCODINGS = ("mono8", "bgr8", "compressed")


SHARED_SEQUENCES = ("kitti_stereo", "kitti_motion", "templeRing")


DEFAULT_START_TIME_S = 1_700_000_000.0


STEREO_TOPICS = ("/left/image_raw", "/right/image_raw")


MOTION_TOPIC = "/image_raw"


STEREO_FRAMES = ("left_camera_optical_frame", "right_camera_optical_frame")


MOTION_FRAME = "camera_optical_frame"


CAMERA_INFO = "sensor_msgs/msg/CameraInfo"


RECTIFIED_ANGLE_RAD = 1e-4  # a stereo rig whose relative rotation is below this is rectified


@dataclass(frozen=True)
class Calibration:
    """The ``sensor_msgs/CameraInfo`` matrices of one camera (plumb_bob, D = 0).

    Attributes:
        K: (3, 3) intrinsics of the images as recorded, pixels.
        R: (3, 3) rectification rotation (identity for a single camera or a rectified rig).
        P: (3, 4) projection in the rectified frame, pixels; the right camera of a stereo rig
            has ``P[0, 3] = -fx' * B`` (B = baseline in the cameras' length unit), as in ROS.
    """

    K: np.ndarray
    R: np.ndarray
    P: np.ndarray


def decompose_camera(P: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(K, R, t) with ``P ~ K [R | t]``, K upper triangular with positive diagonal, K[2,2] = 1."""
    K, R, C = cv2.decomposeProjectionMatrix(np.asarray(P, np.float64))[:3]
    signs = np.diag(np.sign(np.diag(K)))  # make K's diagonal positive (R absorbs the signs)
    K, R = K @ signs, signs @ R
    if np.linalg.det(R) < 0:  # P was given up to a negative scale
        R = -R
    C = C[:3, 0] / C[3, 0]
    return K / K[2, 2], R, -R @ C


def camera_infos(cameras: tuple[np.ndarray, ...], size: tuple[int, int]) -> tuple[Calibration, ...]:
    """CameraInfo matrices of a monocular camera (1 P) or a stereo rig (left, right P).

    Args:
        cameras: (3, 4) projection matrices ``K [R | t]`` in a common world frame.
        size: (width, height) of the images, pixels.
    Returns:
        One :class:`Calibration` per camera. A single camera: R = I, P = [K | 0]. A stereo rig
        whose cameras are parallel (rectified, KITTI): R = I, P = [K | 0] and
        [K_right | (-fx B, 0, 0)]. A converged or offset rig (raw images): R and P from
        ``cv2.stereoRectify`` (zero disparity at infinity), the way ROS's stereo calibration
        fills them.
    """
    parts = [decompose_camera(P) for P in cameras]
    if len(parts) == 1:
        K = parts[0][0]
        return (Calibration(K, np.eye(3), np.hstack([K, np.zeros((3, 1))])),)
    (K_l, R_l, t_l), (K_r, R_r, t_r) = parts
    R_rel = R_r @ R_l.T
    t_rel = t_r - R_rel @ t_l
    angle = float(np.linalg.norm(cv2.Rodrigues(R_rel)[0]))
    if angle < RECTIFIED_ANGLE_RAD:
        P_l = np.hstack([K_l, np.zeros((3, 1))])
        P_r = np.hstack([K_r, np.zeros((3, 1))])
        P_r[0, 3] = K_r[0, 0] * t_rel[0]  # Tx = -fx * B
        return Calibration(K_l, np.eye(3), P_l), Calibration(K_r, np.eye(3), P_r)
    zeros = np.zeros(5)
    R1, R2, P1, P2 = cv2.stereoRectify(
        K_l,
        zeros,
        K_r,
        zeros,
        size,
        R_rel,
        t_rel.reshape(3, 1),
        flags=cv2.CALIB_ZERO_DISPARITY,
        alpha=0,
    )[:4]
    return Calibration(K_l, R1, P1), Calibration(K_r, R2, P2)


def camera_info_message(calibration: Calibration, size: tuple[int, int], header: Header) -> Any:
    """A ``sensor_msgs/CameraInfo`` (plumb_bob, D = 0) for images of ``size`` (width, height)."""
    from sensor_msgs.msg import CameraInfo

    msg = CameraInfo(header=header, width=int(size[0]), height=int(size[1]))
    msg.distortion_model = "plumb_bob"
    msg.d = [0.0] * 5
    msg.k = [float(v) for v in calibration.K.reshape(-1)]
    msg.r = [float(v) for v in calibration.R.reshape(-1)]
    msg.p = [float(v) for v in calibration.P.reshape(-1)]
    return msg


@dataclass(frozen=True)
class SourceFrame:
    """One time step: images (1 = motion, 2 = stereo) loaded lazily, cameras (3x4) or None."""

    paths: tuple[Path, ...] | None
    images: tuple[np.ndarray, ...] | None
    cameras: tuple[np.ndarray, ...] | None

    def load(self) -> tuple[np.ndarray, ...]:
        if self.images is not None:
            return self.images
        assert self.paths is not None
        out = []
        for p in self.paths:
            img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
            if img is None:
                raise BagError(f"cannot read image {p}")
            out.append(img)
        return tuple(out)


def _image_files(folder: Path) -> list[Path]:
    if not folder.is_dir():
        raise BagError(f"image folder not found: {folder}")
    exts = {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm"}
    files = sorted(p for p in folder.iterdir() if p.suffix.lower() in exts)
    if not files:
        raise BagError(f"no images in {folder}")
    return files


def shared_frames(data: Path, sequence: str) -> tuple[str, list[SourceFrame]]:
    """(mode, frames) of a ``../shared/data`` sequence with its cameras (cameras.json)."""
    cams_file = data / "cameras.json"
    if not cams_file.is_file():
        raise BagError(f"shared data not found: {cams_file} does not exist")
    cams = json.loads(cams_file.read_text())

    def cam(rel: str) -> np.ndarray:
        return np.asarray(cams[rel], dtype=np.float64)

    if sequence in ("kitti_stereo", "kitti_motion"):
        lefts = sorted(k for k in cams if k.startswith("kitti_seq2/left/"))
        if sequence == "kitti_motion":
            frames = [SourceFrame((data / k,), None, (cam(k),)) for k in lefts]
            return "motion", frames
        frames = []
        for k in lefts:
            r = k.replace("/left/", "/right/")
            if r in cams:
                frames.append(SourceFrame((data / k, data / r), None, (cam(k), cam(r))))
        return "stereo", frames
    if sequence == "templeRing":
        keys = sorted(k for k in cams if k.startswith("templeRing/"))
        return "motion", [SourceFrame((data / k,), None, (cam(k),)) for k in keys]
    raise BagError(f"unknown shared sequence {sequence!r}; one of {', '.join(SHARED_SEQUENCES)}")


def synthetic_frames(kind: str, n_frames: int, seed: int) -> tuple[str, list[SourceFrame]]:
    """(mode, frames) rendered by :mod:`sepfm_ros.synthetic` (exact cameras)."""
    from sepfm_ros.synthetic.sequences import motion_sequence, stereo_sequence

    if kind == "stereo":
        seq = stereo_sequence(n_frames, seed=seed)
    elif kind == "motion":
        seq = motion_sequence(n_frames, seed=seed)
    else:
        raise BagError(f"--synthetic must be stereo or motion, got {kind!r}")
    frames = [SourceFrame(None, f.images, tuple(c.P for c in f.cameras)) for f in seq]
    return kind, frames


def _convert(img: np.ndarray, encoding: str) -> np.ndarray:
    """A loaded image (grey, BGR or BGRA, 8 or 16 bit) -> mono8 or bgr8 numpy."""
    if img.dtype != np.uint8:
        img = cv2.normalize(img, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    if img.ndim == 3 and img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)
    if encoding == "mono8":
        return img if img.ndim == 2 else cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    return img if img.ndim == 3 else cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)


def image_bytes(img: np.ndarray, encoding: str, header: Header, fmt: str = "png") -> bytes:
    """Serialized sensor_msgs/Image (mono8/bgr8) or CompressedImage (``encoding`` compressed)."""
    if encoding == "compressed":
        return serialize_message(
            numpy_to_compressed(_convert(img, "bgr8" if img.ndim == 3 else "mono8"), fmt, header)
        )
    return serialize_message(numpy_to_image(_convert(img, encoding), encoding, header))


def _header(stamp_ns: int, frame_id: str) -> Header:
    h = Header(frame_id=frame_id)
    h.stamp.sec = int(stamp_ns // 1_000_000_000)
    h.stamp.nanosec = int(stamp_ns % 1_000_000_000)
    return h


def bag_messages(
    mode: str,
    frames: list[SourceFrame],
    rate_hz: float,
    encoding: str,
    start_time_s: float = DEFAULT_START_TIME_S,
    compressed_format: str = "png",
) -> Iterator[tuple[str, str, int, bytes]]:
    """(topic, msgtype, stamp_ns, cdr) of every message, in time order."""
    suffix = "/compressed" if encoding == "compressed" else ""
    msgtype = COMPRESSED_IMAGE if encoding == "compressed" else IMAGE
    t0 = int(round(start_time_s * 1e9))
    dt = int(round(1e9 / rate_hz))
    prev_cam = None
    for k, frame in enumerate(frames):
        stamp = t0 + k * dt
        images = frame.load()
        calibrations = None
        if frame.cameras is not None:
            h, w = images[0].shape[:2]
            calibrations = camera_infos(frame.cameras, (w, h))
        if mode == "stereo":
            for i, (topic, img, fid) in enumerate(
                zip(STEREO_TOPICS, images, STEREO_FRAMES, strict=True)
            ):
                hdr = _header(stamp, fid)
                yield (
                    topic + suffix,
                    msgtype,
                    stamp,
                    image_bytes(img, encoding, hdr, compressed_format),
                )
                if calibrations is not None:
                    info = camera_info_message(calibrations[i], img.shape[1::-1], hdr)
                    yield camera_info_topic(topic), CAMERA_INFO, stamp, serialize_message(info)
            if frame.cameras is not None:
                F = fundamental_from_cameras(frame.cameras[0], frame.cameras[1])
                msg = fundamental_to_image(F, _header(stamp, STEREO_FRAMES[0]))
                yield GROUND_TRUTH_TOPIC, IMAGE, stamp, serialize_message(msg)
        else:
            hdr = _header(stamp, MOTION_FRAME)
            yield (
                MOTION_TOPIC + suffix,
                msgtype,
                stamp,
                image_bytes(images[0], encoding, hdr, compressed_format),
            )
            if calibrations is not None:
                info = camera_info_message(calibrations[0], images[0].shape[1::-1], hdr)
                yield camera_info_topic(MOTION_TOPIC), CAMERA_INFO, stamp, serialize_message(info)
            if frame.cameras is not None and prev_cam is not None:
                F = fundamental_from_cameras(prev_cam, frame.cameras[0])
                yield (
                    GROUND_TRUTH_TOPIC,
                    IMAGE,
                    stamp,
                    serialize_message(fundamental_to_image(F, hdr)),
                )
            prev_cam = frame.cameras[0] if frame.cameras is not None else None


def make_bag(
    out: Path,
    mode: str,
    frames: list[SourceFrame],
    rate_hz: float = 10.0,
    encoding: str = "mono8",
    start_time_s: float = DEFAULT_START_TIME_S,
    compress: bool = False,
    compressed_format: str = "png",
) -> int:
    """Write ``frames`` into a new bag at ``out``; returns the number of messages."""
    check_output_path(out)
    if not frames:
        raise BagError("no frames selected")
    if rate_hz <= 0:
        raise BagError(f"--rate must be > 0, got {rate_hz}")
    count = 0
    with BagWriter(out, flush_interval_s=None, compress=compress) as writer:
        for topic, msgtype, stamp, data in bag_messages(
            mode, frames, rate_hz, encoding, start_time_s, compressed_format
        ):
            writer.add_topic(topic, msgtype)
            writer.write(topic, stamp, data)
            count += 1
    return count
