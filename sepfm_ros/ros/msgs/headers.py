"""Header and stamp helpers, and the ``camera_info`` topic beside an image topic."""

from __future__ import annotations

from builtin_interfaces.msg import Time
from std_msgs.msg import Header


def stamp_ns(stamp: Time) -> int:
    """builtin_interfaces/Time (or any object with ``sec`` and ``nanosec``) -> integer ns.

    The package's one stamp conversion (serialized CDR headers: ``bags.types.header_stamp_ns``).
    """
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def camera_info_topic(image_topic: str) -> str:
    """The ``camera_info`` topic beside an image topic, as image_transport pairs them:
    ``/left/image_raw`` (or ``/left/image_raw/compressed``) -> ``/left/camera_info``."""
    base = image_topic.removesuffix("/compressed")
    parent = base.rsplit("/", 1)[0] if "/" in base else ""
    return parent + "/camera_info"


def copy_header(header: Header) -> Header:
    """An independent copy of a std_msgs/Header."""
    return Header(
        stamp=Time(sec=int(header.stamp.sec), nanosec=int(header.stamp.nanosec)),
        frame_id=str(header.frame_id),
    )
