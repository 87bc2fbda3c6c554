"""``sepfm_ros calibration_check BAG``: is a stereo rig still calibrated? Offline, from a bag.

Every stereo pair of the bag is answered as the live node answers it, with the node's
parameters (``-p NAME:=VALUE``, ``--params-file FILE``: the same matches and F as a node run with
them): estimated in undistorted pixels of K (or rectified pixels: ``-p images:=rectified``, or
topics named ``image_rect``), its inliers measured against the calibration from the bag's
``camera_info`` and fed to the node's sliding-window monitor (``-p calibration_window:=...`` and
the other ``calibration_*`` parameters). Prints one line per pair and the decision; writes
``calibration_check.png`` (error over time) and ``calibration_check.csv`` into ``--out``.

The image topics are ``--left``/``--right`` when given, else picked from the bag as ``process``
picks them (two camera streams whose names differ by left/right). The images pair as in
``process``: the node's approximate-time policy, within half the left camera's frame period
unless ``-p sync_slop_s:=SECONDS`` is given, so a right camera that lags by a few milliseconds
still pairs.

While the decision is WARN or ERROR the session also estimates the rig's corrected rotation from
the matches of the last ``-p correction_window:=N`` usable pairs (default 40); each pair's line
and CSV row carry it. With ``--write-corrected``, when the check ends with a correction, the
corrected calibration goes into ``--out`` as ``left.yaml`` and ``right.yaml``
(``camera_calibration_parsers`` YAML: load them into the camera drivers with
``camera_info_url:=file:///.../left.yaml``): K and D as in the bag's camera_info, R and P of a
new rectification from the corrected extrinsics. Beside them ``correction.json`` holds the
per-axis correction (pitch x, yaw y, roll z of the right camera, degrees), its 95 % interval,
whether yaw was determined, the pairs and matches used and the input. Without a correction no
camera file is written; the reason is printed and written to ``correction.json``
(``"corrected": false``). The exit code does not change with it.

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
)
from sepfm_ros.geometry.calibrated.camera import CalibrationError
from sepfm_ros.ros.bags.errors import BagError
from sepfm_ros.ros.commands.options import add_param_arguments, add_topic_arguments, given_params_of
from sepfm_ros.ros.node.signals import DeferredStop, install_stop_handlers, restore_handlers
from sepfm_ros.ros.offline.corrected_files import write_corrected
from sepfm_ros.ros.offline.rig_check import CheckRequest, check_bag, write_csv, write_plot
from sepfm_ros.ros.session.parameters import ParameterError, monitor_config


def _parse(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        prog="sepfm_ros calibration_check",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("bag", help="input bag: rosbag2 folder, .mcap, .db3 or ROS 1 .bag")
    add_topic_arguments(p, motion=False)
    p.add_argument("--left-info", help="left camera_info topic (default: beside --left)")
    p.add_argument("--right-info", help="right camera_info topic (default: beside --right)")
    p.add_argument("--out", default="calibration_check", help="folder for the PNG and CSV")
    p.add_argument("--max-pairs", type=int, default=0, help="stop after this many pairs (0: all)")
    p.add_argument(
        "--write-corrected",
        action="store_true",
        help="when the check ends with a correction, write the corrected calibration into --out"
        " (left.yaml, right.yaml for camera_info_url) and correction.json beside them; without"
        " one, only correction.json with the reason",
    )
    add_param_arguments(p, "features:=sift, calibration_window:=10, images:=rectified")
    return p.parse_args(argv)


def _request(args: argparse.Namespace) -> CheckRequest:
    """The check the arguments ask for (ParameterError on a bad parameter)."""
    given = given_params_of(args)
    return CheckRequest(
        args.bag,
        given.values,
        args.left,
        args.right,
        args.left_info,
        args.right_info,
        "sync_slop_s" in given.given,
        args.max_pairs,
    )


def main(argv: list[str]) -> int:
    args = _parse(argv)
    stop = DeferredStop()
    previous = install_stop_handlers(stop)
    try:
        request = _request(args)
        run = check_bag(request, stop=stop.check)
    except (BagError, CalibrationError, ParameterError) as err:
        print(f"calibration_check: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("calibration_check: interrupted", file=sys.stderr)
        return 130
    finally:
        restore_handlers(previous)
    rows = run.rows
    if not rows:
        print("calibration_check: no stereo pair could be decoded", file=sys.stderr)
        return 2
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    write_csv(rows, out / "calibration_check.csv")
    write_plot(rows, out / "calibration_check.png", monitor_config(request.values))
    final = rows[-1].status
    print(f"decision: {LEVEL_NAMES[final.level]}: {final.message}")
    print(f"wrote {out / 'calibration_check.png'} and {out / 'calibration_check.csv'}")
    if args.write_corrected:
        try:
            written, line = write_corrected(run, out, args.bag)
        except OSError as err:
            print(
                f"calibration_check: cannot write the corrected calibration: {err}", file=sys.stderr
            )
            return 2
        print(line)
        print("wrote " + ", ".join(str(p) for p in written))
    return 0 if final.level == OK else 1
