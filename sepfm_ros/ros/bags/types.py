"""Message type names, the ROS 2 Jazzy typestore and header-stamp helpers for bags."""

from __future__ import annotations

import struct

from rosbags.typesys import Stores, get_typestore

from sepfm_ros.ros.bags.errors import BagCorruptError

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"
TWO_VIEW_ESTIMATE = "sepfm_msgs/msg/TwoViewEstimate"
MATCH_ARRAY = "sepfm_msgs/msg/MatchArray"
DIAGNOSTIC_ARRAY = "diagnostic_msgs/msg/DiagnosticArray"
DIAGNOSTIC_STATUS = "diagnostic_msgs/msg/DiagnosticStatus"
TRANSFORM_STAMPED = "geometry_msgs/msg/TransformStamped"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
IMAGE_TYPES = (IMAGE, COMPRESSED_IMAGE)

GROUND_TRUTH_TOPIC = "/ground_truth/fundamental"


def header_stamp_ns(data: bytes) -> int:
    """Stamp (ns) of the std_msgs/Header that starts a CDR message (Image, PointCloud2, ...).

    The CDR encapsulation header (4 bytes) is followed by ``int32 sec, uint32 nanosec``; the
    second byte of the encapsulation says the byte order (1 = little endian).
    """
    if len(data) < 12:
        raise BagCorruptError(f"message of {len(data)} bytes is too short to hold a header")
    order = "<" if data[1] & 1 else ">"
    sec, nanosec = struct.unpack_from(order + "iI", data, 4)
    return int(sec) * 1_000_000_000 + int(nanosec)


def has_header(msgtype: str) -> bool:
    """True when messages of ``msgtype`` start with a std_msgs/Header field."""
    try:
        fields = TYPESTORE.fielddefs[msgtype][1]
    except KeyError:
        return False
    if not fields:
        return False
    name, desc = fields[0]
    return name == "header" and "std_msgs/msg/Header" in str(desc)


def format_stamp(ns: int) -> str:
    """Nanoseconds -> ``sec.nanosec``."""
    return f"{ns // 1_000_000_000}.{ns % 1_000_000_000:09d}"
