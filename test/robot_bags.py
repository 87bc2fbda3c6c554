"""Bags written the way a robot records them, with rosbags alone (none of this package's tools).

:func:`write_robot_bag` writes stereo frames as ``/camera/left/image_raw`` and
``/camera/right/image_raw`` (mono8 sensor_msgs/Image), a ``sensor_msgs/CameraInfo`` per camera
on ``/camera/<side>/camera_info``, and ``/tf`` (tf2_msgs/TFMessage, the camera in ``base_link``)
at every frame, in rosbag2 sqlite3, rosbag2 mcap or ROS 1 format, optionally with the right
camera's stamps (and log times) lagging the left by ``right_lag_ns``. Message log times are the
header stamps, as ``ros2 bag record`` on the robot's clock gives them.
"""

from __future__ import annotations

import io
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from sepfm_ros.ros.bags.reader import BagReader
from sepfm_ros.ros.bags.types import header_stamp_ns

FORMATS = ("sqlite3", "mcap", "ros1")
LEFT_TOPIC = "/camera/left/image_raw"
RIGHT_TOPIC = "/camera/right/image_raw"
IMAGE_T = "sensor_msgs/msg/Image"
COMPRESSED_T = "sensor_msgs/msg/CompressedImage"
INFO_T = "sensor_msgs/msg/CameraInfo"
TF_T = "tf2_msgs/msg/TFMessage"
GT_TOPIC = "/ground_truth/fundamental"
START_NS = 1_700_000_000 * 10**9


def _typestore(fmt: str):
    if fmt == "ros1":
        ts = get_typestore(Stores.ROS1_NOETIC)
        # tf2_msgs is not in rosbags' Noetic store; a ROS 1 bag carries its definition anyway
        ts.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", TF_T))
        return ts
    return get_typestore(Stores.ROS2_JAZZY)


def _header(ts, fmt: str, stamp_ns: int, frame_id: str, seq: int):
    Time = ts.types["builtin_interfaces/msg/Time"]
    stamp = Time(sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9)
    Header = ts.types["std_msgs/msg/Header"]
    if fmt == "ros1":
        return Header(seq=seq, stamp=stamp, frame_id=frame_id)
    return Header(stamp=stamp, frame_id=frame_id)


def _image(ts, header, img: np.ndarray):
    """mono8 of an (H, W) array, bgr8 of an (H, W, 3) one."""
    h, w = img.shape[:2]
    colour = img.ndim == 3
    return ts.types[IMAGE_T](
        header=header,
        height=h,
        width=w,
        encoding="bgr8" if colour else "mono8",
        is_bigendian=0,
        step=3 * w if colour else w,
        data=np.ascontiguousarray(img, np.uint8).reshape(-1),
    )


def zero_step_image(ts, header, img: np.ndarray):
    """Like :func:`_image` with ``step`` 0, as some robots' drivers publish (packed rows)."""
    msg = _image(ts, header, img)
    msg.step = 0
    return msg


def big_endian_mono16(ts, header, img: np.ndarray):
    """A mono8 (H, W) array as mono16 big-endian (value x 257, ``is_bigendian`` 1)."""
    h, w = img.shape
    pixels = img.astype(">u2") * np.uint16(257)
    return ts.types[IMAGE_T](
        header=header,
        height=h,
        width=w,
        encoding="mono16",
        is_bigendian=1,
        step=2 * w,
        data=np.frombuffer(pixels.astype(">u2").tobytes(), np.uint8),
    )


def qoi_bytes(img: np.ndarray) -> bytes:
    """A mono8 (H, W) array as QOI data (RGB, grey in every channel), encoded by Pillow."""
    from PIL import Image as PilImage

    out = io.BytesIO()
    PilImage.fromarray(np.dstack([img] * 3)).save(out, format="QOI")
    return out.getvalue()


def qoi_compressed(ts, header, img: np.ndarray):
    """A sensor_msgs/CompressedImage of QOI data (format ``rgb8; qoi compressed rgb8``)."""
    return ts.types[COMPRESSED_T](
        header=header,
        format="rgb8; qoi compressed rgb8",
        data=np.frombuffer(qoi_bytes(img), np.uint8),
    )


def _camera_info(ts, fmt: str, header, size: tuple[int, int], K: np.ndarray, P: np.ndarray):
    roi = ts.types["sensor_msgs/msg/RegionOfInterest"](
        x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
    )
    fields = {
        "d": np.zeros(5),
        "k": np.asarray(K, float).reshape(-1),
        "r": np.eye(3).reshape(-1),
        "p": np.asarray(P, float).reshape(-1),
    }
    if fmt == "ros1":
        fields = {k.upper(): v for k, v in fields.items()}
    return ts.types[INFO_T](
        header=header,
        height=size[1],
        width=size[0],
        distortion_model="plumb_bob",
        binning_x=0,
        binning_y=0,
        roi=roi,
        **fields,
    )


def _tf(ts, header, child: str):
    g = ts.types
    transform = g["geometry_msgs/msg/Transform"](
        translation=g["geometry_msgs/msg/Vector3"](x=0.1, y=0.0, z=1.2),
        rotation=g["geometry_msgs/msg/Quaternion"](x=-0.5, y=0.5, z=-0.5, w=0.5),
    )
    stamped = g["geometry_msgs/msg/TransformStamped"](
        header=header, child_frame_id=child, transform=transform
    )
    return g[TF_T](transforms=[stamped])


def bag_path(folder: Path, fmt: str, name: str = "robot") -> Path:
    """Where :func:`write_robot_bag` writes: a folder for rosbag2, a ``.bag`` file for ROS 1."""
    return folder / (f"{name}.bag" if fmt == "ros1" else f"{name}_{fmt}")


def write_robot_bag(
    path: Path,
    fmt: str,
    frames: Sequence[tuple[np.ndarray, np.ndarray]],
    period_ns: int = 100_000_000,
    right_lag_ns: int = 0,
    K: np.ndarray | None = None,
    baseline_m: float = 0.54,
    topics: tuple[str, str] = (LEFT_TOPIC, RIGHT_TOPIC),
    extra_image_topics: Sequence[str] = (),
    ground_truth: Sequence[np.ndarray] | None = None,
    image: Callable[[Any, Any, np.ndarray], Any] = _image,
    image_type: str = IMAGE_T,
    info_topics: tuple[str, str] | None = None,
) -> Path:
    """Write ``frames`` (left, right mono8 arrays) as a robot's stereo recording; returns ``path``.

    ``extra_image_topics`` get a copy of the left image (for bags with more cameras than two).
    ``ground_truth``: a 3x3 F per frame, written as ``/ground_truth/fundamental`` (Image 64FC1,
    row-major, stamped like the left image) the way ``make_bag`` stores it.
    ``image(typestore, header, array)`` makes each camera message, of type ``image_type``
    (a driver's quirks: :func:`zero_step_image`, :func:`big_endian_mono16`,
    :func:`qoi_compressed`). ``info_topics``: the camera_info topics (default: beside the images).
    """
    if fmt not in FORMATS:
        raise ValueError(f"fmt must be one of {FORMATS}")
    ts = _typestore(fmt)
    h, w = frames[0][0].shape
    if K is None:
        K = np.array([[700.0, 0, w / 2], [0, 700.0, h / 2], [0, 0, 1]])
    P_left = np.hstack([K, np.zeros((3, 1))])
    P_right = P_left.copy()
    P_right[0, 3] = -K[0, 0] * baseline_m
    if fmt == "ros1":
        writer = Writer1(path)
    else:
        plugin = StoragePlugin.SQLITE3 if fmt == "sqlite3" else StoragePlugin.MCAP
        writer = Writer2(path, version=9, storage_plugin=plugin)
    if info_topics is None:
        info_topics = (topics[0].rsplit("/", 1)[0] + "/camera_info",
                       topics[1].rsplit("/", 1)[0] + "/camera_info")  # fmt: skip
    with writer:
        conns = {}
        for topic, msgtype in [
            (topics[0], image_type),
            (topics[1], image_type),
            (info_topics[0], INFO_T),
            (info_topics[1], INFO_T),
            ("/tf", TF_T),
            *[(t, IMAGE_T) for t in extra_image_topics],
            *([(GT_TOPIC, IMAGE_T)] if ground_truth is not None else []),
        ]:
            conns[topic] = writer.add_connection(topic, msgtype, typestore=ts)
        messages = []
        for k, (left, right) in enumerate(frames):
            t_left = START_NS + k * period_ns
            t_right = t_left + right_lag_ns
            hl = _header(ts, fmt, t_left, "left_camera_optical_frame", k)
            hr = _header(ts, fmt, t_right, "right_camera_optical_frame", k)
            messages += [
                (t_left, "/tf", _tf(ts, _header(ts, fmt, t_left, "base_link", k), "camera"), TF_T),
                (t_left, topics[0], image(ts, hl, left), image_type),
                (t_left, info_topics[0], _camera_info(ts, fmt, hl, (w, h), K, P_left), INFO_T),
                (t_right, topics[1], image(ts, hr, right), image_type),
                (t_right, info_topics[1], _camera_info(ts, fmt, hr, (w, h), K, P_right), INFO_T),
            ]
            messages += [(t_left, t, _image(ts, hl, left), IMAGE_T) for t in extra_image_topics]
            if ground_truth is not None:
                F = np.asarray(ground_truth[k], "<f8")
                gt = ts.types[IMAGE_T](
                    header=hl,
                    height=3,
                    width=3,
                    encoding="64FC1",
                    is_bigendian=0,
                    step=24,
                    data=np.frombuffer(F.tobytes(), np.uint8),
                )
                messages.append((t_left, GT_TOPIC, gt, IMAGE_T))
        for t, topic, msg, msgtype in sorted(messages, key=lambda m: m[0]):
            if fmt == "ros1":
                data = ts.serialize_ros1(msg, msgtype)
            else:
                data = ts.serialize_cdr(msg, msgtype)
            writer.write(conns[topic], t, bytes(data))
    return path


def write_camera_bag(
    path: Path,
    frames: Sequence[np.ndarray],
    period_ns: int = 250_000_000,
    topic: str = "/camera/image_raw",
    best_effort: bool = True,
) -> Path:
    """One camera's frames (mono8 (H, W) or bgr8 (H, W, 3) arrays) as ``ros2 bag record`` stores
    a driver's stream, rosbag2 sqlite3, with the QoS the driver offered: the sensor-data profile
    (best effort, keep-last 5) or ROS 2's default (reliable, keep-last 10). Returns ``path``."""
    ts = _typestore("sqlite3")
    inf = QosTime(sec=2147483647, nsec=4294967295)
    qos = Qos(
        history=QosHistory.KEEP_LAST,
        depth=5 if best_effort else 10,
        reliability=QosReliability.BEST_EFFORT if best_effort else QosReliability.RELIABLE,
        durability=QosDurability.VOLATILE,
        deadline=inf,
        lifespan=inf,
        liveliness=QosLiveliness.AUTOMATIC,
        liveliness_lease_duration=inf,
        avoid_ros_namespace_conventions=False,
    )
    with Writer2(path, version=9, storage_plugin=StoragePlugin.SQLITE3) as writer:
        conn = writer.add_connection(topic, IMAGE_T, typestore=ts, offered_qos_profiles=[qos])
        for k, img in enumerate(frames):
            t = START_NS + k * period_ns
            msg = _image(ts, _header(ts, "sqlite3", t, "camera_optical_frame", k), img)
            writer.write(conn, t, bytes(ts.serialize_cdr(msg, IMAGE_T)))
    return path


def write_stereo_without_right(path: Path, left: np.ndarray, ground_truth: bool = False) -> Path:
    """A rosbag2 stereo bag whose right topic was recorded but holds no message."""
    ts = _typestore("mcap")
    with Writer2(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conn_l = writer.add_connection(LEFT_TOPIC, IMAGE_T, typestore=ts)
        writer.add_connection(RIGHT_TOPIC, IMAGE_T, typestore=ts)
        header = _header(ts, "mcap", START_NS, "left", 0)
        writer.write(conn_l, START_NS, bytes(ts.serialize_cdr(_image(ts, header, left), IMAGE_T)))
        if ground_truth:
            gt = writer.add_connection(GT_TOPIC, IMAGE_T, typestore=ts)
            F = np.frombuffer(np.eye(3).tobytes(), np.uint8)
            msg = ts.types[IMAGE_T](
                header=header, height=3, width=3, encoding="64FC1", is_bigendian=0, step=24, data=F
            )
            writer.write(gt, START_NS, bytes(ts.serialize_cdr(msg, IMAGE_T)))
    return path


def header_stamps(bag: Path, topic: str) -> list[int]:
    """The header stamps (ns) of ``topic``'s messages in ``bag``, in bag order."""
    with BagReader(bag) as reader:
        return [header_stamp_ns(m.data) for m in reader.messages([topic])]
