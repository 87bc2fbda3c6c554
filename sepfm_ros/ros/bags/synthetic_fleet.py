"""A fleet of calibrated stereo bags with known drift, for the audit's tests and benchmark.

Every rig records KITTI's rectified stereo frames (``../shared/data``) at 10 Hz with its own
camera_info (KITTI's calibration; the rig's own optical frame ids, so each rig is its own by
what its bags say) into rosbag2 bags, one folder per day. A rig may drift: from a given bag and
frame on, its right camera is rotated by ``drift_deg`` about the camera's x axis (the images
warped by K R K^-1), in that bag and every later one. The calibration check ignores yaw by
design, so the drift is a pitch: what a knock to a stereo bar does.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from rclpy.serialization import serialize_message

from sepfm_ros.ros.bags.reader import RawMessage
from sepfm_ros.ros.bags.synthesis import (
    STEREO_TOPICS,
    _header,
    camera_info_message,
    camera_infos,
    image_bytes,
    shared_frames,
)
from sepfm_ros.ros.bags.types import CAMERA_INFO, IMAGE
from sepfm_ros.ros.bags.writer import write_bag
from sepfm_ros.ros.msgs.headers import camera_info_topic

DAY_NS = 86_400 * 10**9
HOUR_NS = 3_600 * 10**9
FLEET_START_NS = 1_780_000_000 * 10**9  # the first day's midnight-ish, UTC


@dataclass(frozen=True)
class RigPlan:
    """One rig of the fleet: its name, and where its drift starts (bag index, frame index;
    None: it holds its calibration)."""

    name: str
    drift_from: tuple[int, int] | None = None
    drift_deg: float = 0.5


@dataclass(frozen=True)
class FleetBag:
    """A bag written by :func:`make_fleet`: its path, rig, day, start (ns) and the frame the
    drift starts at within it (None: no drift starts in this bag)."""

    path: Path
    rig: str
    day: int
    start_ns: int
    drift_frame: int | None
    drifted: bool


def _rotation_homography(K: np.ndarray, deg: float) -> np.ndarray:
    """(3, 3) K R_x(deg) K^-1: the image of a camera turned by ``deg`` about its x axis."""
    R = cv2.Rodrigues(np.array([np.radians(deg), 0.0, 0.0]))[0]
    return K @ R @ np.linalg.inv(K)


def _messages(
    rig: str,
    calibs: tuple,
    frames: list,
    start_ns: int,
    period_ns: int,
    drift_frame: int | None,
    drift_deg: float,
) -> Iterator[RawMessage]:
    """A rig's stereo frames with its camera_info ``calibs`` (left, right), the right image
    rotated from ``drift_frame`` on."""
    for k, frame in enumerate(frames):
        stamp = start_ns + k * period_ns
        left, right = (np.asarray(i) for i in frame.load())
        h, w = left.shape[:2]
        if drift_frame is not None and k >= drift_frame:
            H = _rotation_homography(calibs[1].K, drift_deg)
            right = cv2.warpPerspective(right, H, (w, h))
        for side, topic, img, calib in zip(
            ("left", "right"), STEREO_TOPICS, (left, right), calibs, strict=True
        ):
            hdr = _header(stamp, f"{rig}_{side}_camera_optical_frame")
            yield RawMessage(topic, IMAGE, stamp, image_bytes(img, "mono8", hdr))
            info = camera_info_message(calib, (w, h), hdr)
            yield RawMessage(camera_info_topic(topic), CAMERA_INFO, stamp, serialize_message(info))


def make_fleet(
    out: Path,
    shared_data: Path,
    rigs: list[RigPlan],
    bags_per_rig: int = 2,
    frames_per_bag: int = 20,
    rate_hz: float = 10.0,
) -> list[FleetBag]:
    """Write each rig's ``bags_per_rig`` bags (one a day, ``out/day<d>/<rig>_<d>``) of
    ``frames_per_bag`` consecutive KITTI stereo frames, each bag from a different start
    frame; returns the bags written."""
    mode, frames = shared_frames(shared_data, "kitti_stereo")
    assert mode == "stereo"
    if frames_per_bag > len(frames):
        raise ValueError(f"frames_per_bag {frames_per_bag} > the {len(frames)} KITTI frames")
    period = int(round(1e9 / rate_hz))
    # one stored calibration for every rig and bag, as a rig's driver publishes it (KITTI's
    # per-frame projections differ in their last digits, which the node would take as a new
    # calibration every frame)
    h, w = np.asarray(frames[0].load()[0]).shape[:2]
    calibs = camera_infos(frames[0].cameras, (w, h))
    written = []
    for r, plan in enumerate(rigs):
        for d in range(bags_per_rig):
            first = (7 * r + 11 * d) % (len(frames) - frames_per_bag + 1)
            chunk = frames[first : first + frames_per_bag]
            start = FLEET_START_NS + d * DAY_NS + r * HOUR_NS
            drift_frame = None
            drifted = False
            if plan.drift_from is not None:
                bag_k, frame_k = plan.drift_from
                if d == bag_k:
                    drift_frame, drifted = frame_k, True
                elif d > bag_k:
                    drift_frame, drifted = 0, True
            path = out / f"day{d}" / f"{plan.name}_{d}"
            path.parent.mkdir(parents=True, exist_ok=True)
            msgs = _messages(plan.name, calibs, chunk, start, period, drift_frame, plan.drift_deg)
            write_bag(path, msgs)
            written.append(
                FleetBag(
                    path,
                    plan.name,
                    d,
                    start,
                    drift_frame if d == (plan.drift_from or (-1,))[0] else None,
                    drifted,
                )
            )
    return written
