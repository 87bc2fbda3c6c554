"""``sepfm_ros calibration_check BAG``: is a stereo rig still calibrated? Offline, from a bag.

For every stereo pair in the bag, matches the images with the node's pipeline (estimated in
undistorted pixels of K, or rectified pixels), measures the inlier matches against the
calibration from the bag's ``camera_info`` topics
(:mod:`sepfm_ros.geometry.calibrated.calibration_check`)
and runs the same sliding-window monitor as the node. Prints one line per pair and the
decision; writes ``calibration_check.png`` (error over time) and ``calibration_check.csv`` into
``--out``.

The image topics are ``--left``/``--right`` when given, else picked from the bag as ``process``
picks them (two camera streams whose names differ by left/right). The images pair as in
``process``: the node's approximate-time policy, within half the left camera's frame period
unless ``--sync-slop`` is given, so a right camera that lags by a few milliseconds still pairs.

Exit code: 0 when the final decision is OK, 1 when WARN, ERROR or not enough usable pairs
(STALE), 2 on bad input (no such bag or topic, no camera_info, unusable calibration).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from sepfm_ros.geometry.calibrated.calibration_check import (
    LEVEL_NAMES,
    OK,
    MonitorConfig,
)
from sepfm_ros.geometry.calibrated.camera import CalibrationError
from sepfm_ros.ros.bags.errors import BagError
from sepfm_ros.ros.node.signals import DeferredStop, install_stop_handlers, restore_handlers
from sepfm_ros.ros.offline.rig_check import _monitor_config, run_check, write_csv, write_plot


def _parse(argv: list[str]) -> argparse.Namespace:
    d = MonitorConfig()
    p = argparse.ArgumentParser(
        prog="sepfm_ros calibration_check",
        description="Check a stereo rig's calibration (camera_info) against its images in a bag.",
    )
    p.add_argument("bag", help="input bag: rosbag2 folder, .mcap, .db3 or ROS 1 .bag")
    p.add_argument("--left", help="left image topic (default: picked from the bag)")
    p.add_argument("--right", help="right image topic (default: picked from the bag)")
    p.add_argument("--left-info", help="left camera_info topic (default: beside --left)")
    p.add_argument("--right-info", help="right camera_info topic (default: beside --right)")
    p.add_argument(
        "--rectified",
        choices=("auto", "yes", "no"),
        default="auto",
        help="images are rectified (image_rect); auto: when the topic names say image_rect",
    )
    p.add_argument("--out", default="calibration_check", help="folder for the PNG and CSV")
    p.add_argument("--window", type=int, default=d.window, help="pairs in the sliding window")
    p.add_argument("--min-pairs", type=int, default=d.min_pairs, help="usable pairs to decide")
    p.add_argument("--min-inliers", type=int, default=d.min_inliers, help="inliers per pair")
    p.add_argument("--warn-epipolar-px", type=float, default=d.warn_epipolar_px)
    p.add_argument("--error-epipolar-px", type=float, default=d.error_epipolar_px)
    p.add_argument("--warn-rotation-deg", type=float, default=d.warn_rotation_deg)
    p.add_argument("--error-rotation-deg", type=float, default=d.error_rotation_deg)
    p.add_argument("--max-pairs", type=int, default=0, help="stop after this many pairs (0: all)")
    p.add_argument(
        "--sync-slop",
        type=float,
        metavar="SECONDS",
        help="largest stamp difference of a stereo pair (default: just under half the left "
        "camera's frame period)",
    )
    return p.parse_args(argv)


def main(argv: list[str]) -> int:
    args = _parse(argv)
    stop = DeferredStop()
    previous = install_stop_handlers(stop)
    try:
        rows = run_check(args, stop=stop)
    except (BagError, CalibrationError, ValueError) as err:
        print(f"calibration_check: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("calibration_check: interrupted", file=sys.stderr)
        return 130
    finally:
        restore_handlers(previous)
    if not rows:
        print("calibration_check: no stereo pair could be decoded", file=sys.stderr)
        return 2
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    write_csv(rows, out / "calibration_check.csv")
    write_plot(rows, out / "calibration_check.png", _monitor_config(args))
    final = rows[-1].status
    print(f"decision: {LEVEL_NAMES[final.level]}: {final.message}")
    print(f"wrote {out / 'calibration_check.png'} and {out / 'calibration_check.csv'}")
    return 0 if final.level == OK else 1
