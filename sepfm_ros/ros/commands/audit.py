"""``sepfm_ros audit BAGS... -o OUT``: every rig's calibration across many bags, on Dask.

BAGS are bags (rosbag2 folders, ``.mcap``, ``.db3``, ROS 1 ``.bag``), folders searched for bags,
glob patterns or text files listing them. Each bag is read on a worker of the engine (Dask
distributed: a local cluster of one single-threaded worker process per core, or the cluster at
``--address``): its inputs are picked as ``process`` picks them, its rig named by what it says
(camera_info frame ids, K, D, P and topics; ``--rig-from`` names rigs by a path pattern), and
every pair answered by the node's answer path: the calibration check where the bag has
calibrated stereo, otherwise the answer statistics. A bag longer than ``--slice-s`` is split
into time slices that run in parallel and give the same answers as one pass.

OUT gets ``bags.csv`` (a row per bag: rig, time span, topics, pairs, pairs with F, inlier error,
rotation drift against the calibration, worst decision, when the drift starts and when it was
flagged, and for a flagged bag the corrected rotation (pitch, yaw, roll, degrees) with its 95 %
interval, or why there is none; a bag that cannot be read gets a row with the reason),
``pairs.csv`` (every pair) and ``report.md`` with a drift plot per rig, flagged rigs first. Rows
are written by this process as bags finish; running the same command again skips the bags done
(same bag files, parameters and version) unless ``--force``.

Exit codes: 0 every bag answered and no rig flagged; 1 a rig flagged (WARN or ERROR) or a bag
without an answer; 2 bad arguments or no engine; 130 interrupted (rows written so far stay).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from sepfm_ros.fleet.engine import EngineError, default_workers
from sepfm_ros.fleet.records import (
    InputChoice,
    Thresholds,
)
from sepfm_ros.fleet.rigs import (
    RigPatternError,
    compile_pattern,
)
from sepfm_ros.ros.bags.errors import BagError
from sepfm_ros.ros.commands.options import add_param_arguments, add_topic_arguments, given_params_of
from sepfm_ros.ros.offline.audit import DEFAULT_SLICE_S, Options, run_audit
from sepfm_ros.ros.session.parameters import monitor_config


def _parse(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        prog="sepfm_ros audit",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("bags", nargs="+", help="bags, folders, glob patterns or .txt lists of bags")
    p.add_argument("-o", "--output", type=Path, required=True, help="output folder")
    p.add_argument(
        "--address",
        help="Dask scheduler of a running cluster (tcp://HOST:8786); default: a local cluster",
    )
    p.add_argument(
        "--workers",
        type=int,
        default=None,
        help=f"worker processes of the local cluster (default: one per core, {default_workers()})",
    )
    p.add_argument(
        "--slice-s",
        type=float,
        default=DEFAULT_SLICE_S,
        help="split bags longer than this into time slices of at most this many seconds (0: never)",
    )
    p.add_argument(
        "--rig-from",
        metavar="REGEX",
        help="name rigs by this regular expression on the bag path (its 'rig' group, else its "
        "first group), e.g. 'robots/(?P<rig>[^/]+)/'; default: by the cameras' camera_info",
    )
    p.add_argument("--force", action="store_true", help="audit bags done in an earlier run again")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.add_argument("--mode", choices=("stereo", "motion"), help="default: from each bag")
    add_topic_arguments(p)
    add_param_arguments(p, "seed:=0, calibration_window:=10")
    return p.parse_args(argv)


def _options(args: argparse.Namespace) -> Options:
    """The run's options; BagError / ValueError / RigPatternError on bad arguments."""
    given = given_params_of(args)
    params = given.values
    monitor = monitor_config(params)
    if args.slice_s < 0:
        raise ValueError(f"--slice-s must be >= 0, got {args.slice_s}")
    if args.workers is not None and args.workers < 1:
        raise ValueError(f"--workers must be >= 1, got {args.workers}")
    choice = InputChoice(
        args.mode,
        args.left,
        args.right,
        args.image,
        "sync_slop_s" in given.given,
    )
    return Options(
        params,
        choice,
        args.slice_s,
        Thresholds(monitor.warn_rotation_deg, monitor.error_rotation_deg),
        compile_pattern(args.rig_from),
        not args.quiet,
    )


def main(argv: list[str]) -> int:
    args = _parse(argv)
    try:
        opts = _options(args)
        rows, report = run_audit(
            args.bags, args.output, opts, args.address, args.workers, args.force
        )
    except (BagError, ValueError, RigPatternError, EngineError) as err:
        print(f"sepfm_ros audit: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(
            f"sepfm_ros audit: interrupted; {args.output / 'bags.csv'} holds the bags finished "
            "so far (rerun the command to continue)",
            file=sys.stderr,
        )
        return 130
    failed = [r for r in rows if r["state"] != "done"]
    flagged = sorted({r["rig"] for r in rows if r.get("worst_level") in ("WARN", "ERROR")})
    print(
        f"{len(rows)} bag(s): {len(rows) - len(failed)} answered, {len(failed)} without an "
        f"answer; {len(flagged)} rig(s) flagged" + (f": {', '.join(flagged)}" if flagged else "")
    )
    print(f"wrote {args.output / 'bags.csv'}, {args.output / 'pairs.csv'} and {report}")
    return 1 if failed or flagged else 0
