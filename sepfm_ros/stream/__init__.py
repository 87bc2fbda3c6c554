"""Stream logic of the node and the offline tools, without ROS: which frames pair, when a pair is
worked on, and how healthy the input is.

Nothing here imports rclpy or a ROS message package (``test/stream/test_stream_no_ros.py``
checks it), so the
rules are tested without DDS and shared by the live node, ``process``, ``eval --bags`` and
``calibration_check``:

- :mod:`sepfm_ros.stream.sync`: approximate-time pairing of two streams by stamp (integer ns);
- :mod:`sepfm_ros.stream.pairing`: stereo pairing by stamp, motion pairing by frame gap, and the
  reset when the input's stamps jump back;
- :mod:`sepfm_ros.stream.scheduling`: the latest-only slots between input, match and estimate
  threads, and the saturation policy;
- :mod:`sepfm_ros.stream.health`: counters, recent-window problems, stalls, the health level and
  log throttling.

The ROS adapters (:mod:`sepfm_ros.ros`) turn messages into stamps and frames for these and
publish what they decide.
"""

from sepfm_ros.stream.health import ERROR, OK, WARN, Health, LogThrottle, RecentEvents
from sepfm_ros.stream.pairing import (
    Frame,
    MotionPairing,
    PairOutcome,
    StereoPairing,
    stamp_order_effects,
)
from sepfm_ros.stream.scheduling import PairScheduler
from sepfm_ros.stream.sync import LEFT, RIGHT, ApproximateTimeSync, SyncStats

__all__ = [
    "ERROR",
    "LEFT",
    "OK",
    "RIGHT",
    "WARN",
    "ApproximateTimeSync",
    "Frame",
    "Health",
    "LogThrottle",
    "MotionPairing",
    "PairOutcome",
    "PairScheduler",
    "RecentEvents",
    "StereoPairing",
    "SyncStats",
    "stamp_order_effects",
]
