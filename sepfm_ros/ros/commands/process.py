"""``sepfm_ros process BAG -o OUT``: the node's pipeline over a bag, without DDS.

BAG is a rosbag2 bag (sqlite3 or mcap) or a ROS 1 ``.bag`` file. The input images are the topics
given with ``--left TOPIC --right TOPIC`` (stereo) or ``--image TOPIC`` (motion), Image or
CompressedImage; without them they are picked from the bag (one camera: motion; two whose names
differ by left/right: stereo; the pick is printed) or, when the bag holds several cameras, an
error lists its image topics. The images are paired as the node does (its approximate-time
policy for stereo, frame t - ``frame_gap`` and t for motion), except that stereo pairs form
within half the left frame period unless ``-p sync_slop_s:=...`` is given, so a right camera that
lags by 10-20 ms still pairs. Irregular header stamps are handled as the node handles them, with
a warning per topic: a frame whose stamp repeats or steps back is skipped, and a jump back of
more than ``stamp_jump_reset_s`` (a looped bag, a restarted driver) restarts the pairing there.
The command runs the node's
:class:`~sepfm_ros.pipeline.pipeline.Pipeline` with the same parameters (``-p name:=value``,
the node's parameter names, e.g. ``-p seed:=0 -p method:=sep5``) and writes
the node's outputs with the source stamps to OUT: ``/sepfm/estimate`` (sepfm_msgs/TwoViewEstimate,
one per pair, a failure record for a pair that cannot be used), ``/sepfm/matches``
(sepfm_msgs/MatchArray), with camera_info the pose (stereo: ``/sepfm/relative_transform``
and ``/sepfm/relative_pose``; motion: ``/sepfm/angular_velocity`` and
``/sepfm/translation_direction``) and ``/sepfm/calibration_check``
(diagnostic_msgs/DiagnosticArray stamped with the pair's header; plus a copy of
``/ground_truth/fundamental`` when BAG has it),
logged at the log time of the input message that completed each pair, so OUT plays in step
with BAG. The answers are the node's (:mod:`sepfm_ros.ros.session.answer`).

A progress bar runs on stderr (``--print-done`` also prints a line ``done K/N STAMP`` on stdout for
each pair once its results are safely in OUT, for programs that watch the progress); at the end a
summary (per-frame table with ``--table``) is printed,
scored against the ground truth when the bag has it. Every result is flushed to OUT as soon as it
is computed (see :class:`~sepfm_ros.ros.bags.writer.BagWriter`), so Ctrl-C, SIGTERM or even SIGKILL
leave a readable OUT holding every result computed before the interruption.

Exit codes: 0 done, 1 bad input (message on stderr, no traceback: an unreadable bag, no pair to
form, an output name of another format, no pair whose images decode), 130 interrupted.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from sepfm_ros.ros.bags.errors import BagError
from sepfm_ros.ros.bags.results import (
    format_summary,
    format_table,
    read_results,
    summarize,
)
from sepfm_ros.ros.commands.options import add_param_arguments, add_topic_arguments, given_params_of
from sepfm_ros.ros.node.signals import DeferredStop, install_stop_handlers, restore_handlers
from sepfm_ros.ros.offline.process import ProcessInputs, decoded, run_process
from sepfm_ros.ros.session.parameters import (
    ParameterError,
)


def _parse(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        prog="sepfm_ros process",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("bag", type=Path, help="input bag: rosbag2 folder, .mcap, .db3 or ROS 1 .bag")
    p.add_argument("-o", "--output", type=Path, required=True, help="output bag (must not exist)")
    p.add_argument("--mode", choices=("stereo", "motion"), help="default: from the bag's topics")
    add_topic_arguments(p)
    add_param_arguments(p, "seed:=0, method:=sep5, features:=orb")
    p.add_argument("--table", action="store_true", help="print the per-frame table")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument(
        "--print-done",
        action="store_true",
        help="print 'done K/N SEC.NANOSEC' on stdout when a pair's results are safely written",
    )
    return p.parse_args(argv)


def print_done(k: int, total: int, stamp: int) -> None:
    """``--print-done``: one flushed line per pair whose results are in the output bag."""
    print(f"done {k}/{total} {stamp // 1_000_000_000}.{stamp % 1_000_000_000:09d}", flush=True)


def main(argv: list[str]) -> int:
    args = _parse(argv)
    stop = DeferredStop()
    previous = install_stop_handlers(stop)
    interrupted = False
    try:
        given = given_params_of(args)
        choice = ProcessInputs(
            args.mode, args.left, args.right, args.image, "sync_slop_s" in given.given
        )
        done, total = run_process(
            args.bag,
            args.output,
            given.values,
            choice,
            not args.quiet,
            on_done=print_done if args.print_done else None,
            stop=stop.check,
        )
    except (BagError, ParameterError) as err:
        print(f"sepfm_ros process: error: {err}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        interrupted = True
        done, total = -1, -1
    finally:
        restore_handlers(previous)
    if interrupted and not args.output.exists():
        print("sepfm_ros process: interrupted before any output", file=sys.stderr)
        return 130
    try:
        results = read_results(args.output)
    except BagError as err:
        print(f"sepfm_ros process: error reading back {args.output}: {err}", file=sys.stderr)
        return 1
    if args.table:
        print(format_table(results))
    undecoded = not interrupted and total > 0 and not any(decoded(r) for r in results)
    expected = None if interrupted else total
    print(format_summary(summarize(results, expected)))
    if interrupted:
        print(
            f"sepfm_ros process: interrupted; {args.output} holds the {len(results)} results "
            "computed before the interruption",
            file=sys.stderr,
        )
        return 130
    print(f"wrote {args.output}: {done} of {total} pairs")
    if undecoded:
        print(
            f"sepfm_ros process: error: none of the {total} pairs could be decoded (the reasons "
            "are above)",
            file=sys.stderr,
        )
        return 1
    return 0
