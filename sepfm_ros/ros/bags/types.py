"""Message type names, the typestore (ROS 2 Jazzy's and sepfm_msgs') and header-stamp helpers.

The sepfm_msgs types are registered from the ``.msg`` files of the installed interface package
(``share/sepfm_msgs/msg`` of the prefix that holds its generated Python package), so a bag
written with :data:`TYPESTORE` stores their definitions and RIHS01 hashes, and readers without
this project (plain rosbags, Foxglove) decode them.
"""

from __future__ import annotations

import importlib.util
import struct
from pathlib import Path

from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from sepfm_ros.ros.bags.errors import BagCorruptError

SEPFM_MSGS = "sepfm_msgs"
TWO_VIEW_ESTIMATE = "sepfm_msgs/msg/TwoViewEstimate"
MATCH_ARRAY = "sepfm_msgs/msg/MatchArray"
MATCH = "sepfm_msgs/msg/Match"
STAGE_TIMING = "sepfm_msgs/msg/StageTiming"
SEPFM_MSG_TYPES = (STAGE_TIMING, MATCH, MATCH_ARRAY, TWO_VIEW_ESTIMATE)


def sepfm_msgs_share() -> Path | None:
    """``share/sepfm_msgs`` of the installed interface package, None when it is not installed.

    Found from its generated Python package (``<prefix>/lib/pythonX.Y/site-packages/sepfm_msgs``
    in a virtual environment, a colcon install or /opt/ros): the nearest ancestor folder holding
    ``share/sepfm_msgs/package.xml``. The source folder ``sepfm_msgs/`` of a checkout has no
    ``__init__.py`` and is no installed package.
    """
    spec = importlib.util.find_spec(SEPFM_MSGS)
    if spec is None or spec.origin is None or not Path(spec.origin).is_file():
        return None
    # not resolved: a symlinked install (colcon --symlink-install) points into the build folder
    for folder in Path(spec.origin).absolute().parents:
        share = folder / "share" / SEPFM_MSGS
        if (share / "package.xml").is_file():
            return share
    return None


def register_sepfm_msgs(typestore: Typestore) -> bool:
    """Register the sepfm_msgs types with ``typestore`` from the installed ``.msg`` files.

    Returns False (nothing registered) when sepfm_msgs is not installed.
    """
    share = sepfm_msgs_share()
    if share is None:
        return False
    types = {}
    for name in SEPFM_MSG_TYPES:
        path = share / "msg" / f"{name.rsplit('/', 1)[1]}.msg"
        types.update(get_types_from_msg(path.read_text(encoding="utf-8"), name))
    typestore.register(types)
    return True


TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
register_sepfm_msgs(TYPESTORE)

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"
DIAGNOSTIC_ARRAY = "diagnostic_msgs/msg/DiagnosticArray"
DIAGNOSTIC_STATUS = "diagnostic_msgs/msg/DiagnosticStatus"
TRANSFORM_STAMPED = "geometry_msgs/msg/TransformStamped"
POSE_WITH_COVARIANCE_STAMPED = "geometry_msgs/msg/PoseWithCovarianceStamped"
TWIST_WITH_COVARIANCE_STAMPED = "geometry_msgs/msg/TwistWithCovarianceStamped"
VECTOR3_STAMPED = "geometry_msgs/msg/Vector3Stamped"
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
