"""``sepfm_ros eval`` / ``ros2 run sepfm_ros eval``: compare estimators on pairs with ground truth.

Example (the README's command, from the repository root)::

    sepfm_ros eval --manifest ../shared/data/pairs.json --out docs/eval --readme README.md

writes ``docs/eval/report.md`` with tables, PNG figures and per-run CSVs, and the overall table
into README.md between its ``eval-table`` markers. Matches are cached in ``.cache/eval_matches``.
Pairs that cannot be evaluated (missing image, malformed F, fewer than 8 matches, ...) are listed
in the report with the reason; they do not stop the run. Exit code 0 when at least one pair was
evaluated, 1 when none was or a ``--bags`` path gave no pair (missing, unreadable, no ground
truth, too few frames: the report is still written), 2 on bad arguments or an unreadable
manifest.

``--bags PATH`` (repeatable) adds pairs from a bag or a folder of bags with ground truth: input
bags (pairs as ``process`` forms them: the session's pairing, with the node's parameters from
``-p NAME:=VALUE`` and ``--params-file FILE``; rosbag2 sqlite3/mcap or ROS 1 ``.bag``; input
topics from ``--left``/``--right`` or ``--image``, else picked from each bag) or bags written by
``process`` (the node's own matches); see :mod:`sepfm_ros.evaluation.bags`.
"""

from __future__ import annotations

import argparse
import shlex
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from sepfm_ros.evaluation.manifest import ManifestError, PairSpec, load_cameras, load_manifest
from sepfm_ros.evaluation.matches_cache import MatchesCache, MatchSettings
from sepfm_ros.evaluation.methods import REGISTRY, available_methods, resolve_methods
from sepfm_ros.evaluation.report import update_readme, write_report
from sepfm_ros.evaluation.run import EvalConfig, evaluate
from sepfm_ros.pipeline.features import FEATURES
from sepfm_ros.ros.commands.options import add_param_arguments, add_topic_arguments


@dataclass
class Loaded:
    """What the inputs gave: pairs, the reasons of those that cannot be evaluated, GT cameras
    and the ``--bags`` paths that gave no pair."""

    pairs: list[PairSpec] = field(default_factory=list)
    errors: list = field(default_factory=list)
    cameras: dict = field(default_factory=dict)
    unusable_bags: list[str] = field(default_factory=list)


def _int_list(text: str) -> tuple[int, ...]:
    try:
        vals = tuple(int(t) for t in text.split(",") if t.strip())
    except ValueError:
        msg = f"expected comma-separated integers, got {text!r}"
        raise argparse.ArgumentTypeError(msg) from None
    if not vals:
        raise argparse.ArgumentTypeError("expected at least one seed")
    return vals


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="sepfm_ros eval",
        description="Evaluate fundamental-matrix estimators on image pairs with ground-truth F "
        "and write a markdown report with PNG figures.",
    )
    _add_input_arguments(p)
    _add_run_arguments(p)
    return p


def _add_input_arguments(p: argparse.ArgumentParser) -> None:
    """Where the pairs come from: a manifest and/or bags (their topics and pairing)."""
    p.add_argument(
        "--manifest",
        type=Path,
        default=None,
        help="JSON list of pairs in the format of ../shared/data/pairs.json",
    )
    p.add_argument(
        "--bags",
        type=Path,
        action="append",
        default=[],
        help="a bag, or a folder of bags, with /ground_truth/fundamental: input bags (images, "
        "as made by make_bag or recorded) or bags written by process; repeatable",
    )
    add_topic_arguments(p, prefix="--bags: ")
    add_param_arguments(p, "sync_slop_s:=0.02, frame_gap:=2: the pairing of --bags")
    p.add_argument(
        "--root",
        type=Path,
        default=None,
        help="folder the manifest's image paths are relative to (default: its folder)",
    )
    p.add_argument(
        "--cameras",
        type=Path,
        default=None,
        help="JSON of GT 3x4 cameras by image path, for relative-pose errors "
        "(default: cameras.json beside the manifest, when there is one)",
    )


def _add_run_arguments(p: argparse.ArgumentParser) -> None:
    """Matching, methods, seeds, thresholds and the report."""
    p.add_argument(
        "--out", type=Path, default=Path("eval_report"), help="report folder (default: eval_report)"
    )
    p.add_argument(
        "--cache",
        type=Path,
        default=Path(".cache/eval_matches"),
        help="folder for cached matches, keyed by image content + settings "
        "(default: .cache/eval_matches); 'none' disables caching",
    )
    p.add_argument(
        "--features",
        choices=FEATURES,
        default="sift",
        help="default: sift; akaze where this OpenCV has it (OpenCV 4, OpenCV 5's contrib wheel)",
    )
    p.add_argument("--ratio", type=float, default=0.8, help="Lowe ratio test (default: 0.8)")
    p.add_argument(
        "--max-features",
        type=int,
        default=0,
        help="detector feature cap, 0 = detector default (SIFT unlimited, ORB 2000)",
    )
    p.add_argument(
        "--methods",
        default="all",
        help="comma list of methods, or all / ours / opencv (default: all available: "
        f"{', '.join(available_methods())}); known: {', '.join(REGISTRY)}",
    )
    p.add_argument(
        "--seeds",
        type=_int_list,
        default=(0, 1, 2),
        help="comma-separated seeds each method runs with (default: 0,1,2)",
    )
    p.add_argument(
        "--threshold",
        type=float,
        default=1.0,
        help="inlier threshold in px (symmetric epipolar distance), same for all "
        "methods (default: 1.0; the paper used 3)",
    )
    p.add_argument("--confidence", type=float, default=0.99, help="RANSAC confidence (0.99)")
    p.add_argument(
        "--baseline", default="ransac8", help="method of the paired comparisons (default: ransac8)"
    )
    p.add_argument("--scenes", default="", help="comma list of scenes to keep (default: all)")
    p.add_argument(
        "--max-pairs",
        type=int,
        default=0,
        help="evaluate at most this many pairs, evenly spaced over the manifest (default: 0 = all)",
    )
    p.add_argument(
        "--readme",
        type=Path,
        default=None,
        help="also write the overall table between the eval-table markers of this file",
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def select_pairs(pairs: list[PairSpec], scenes: str, max_pairs: int) -> list[PairSpec]:
    """Keep the named scenes, then at most ``max_pairs`` evenly spaced pairs (deterministic)."""
    keep = {s.strip() for s in scenes.split(",") if s.strip()}
    if keep:
        pairs = [p for p in pairs if p.scene in keep]
    if max_pairs and len(pairs) > max_pairs:
        step = len(pairs) / max_pairs
        pairs = [pairs[int(i * step)] for i in range(max_pairs)]
    return pairs


def _checked(parser: argparse.ArgumentParser, args: argparse.Namespace) -> tuple:
    """The match settings and methods of the arguments (exits with 2 on a bad argument)."""
    try:
        settings = MatchSettings(args.features, args.ratio, args.max_features)
        methods = resolve_methods(args.methods)
    except ValueError as exc:
        parser.error(str(exc))
    if not 0.0 < args.confidence < 1.0:
        parser.error(f"--confidence must be in (0, 1), got {args.confidence}")
    if args.threshold <= 0:
        parser.error(f"--threshold must be positive, got {args.threshold}")
    if args.baseline not in REGISTRY:
        parser.error(f"unknown --baseline {args.baseline!r}; known: {', '.join(REGISTRY)}")
    if args.manifest is None and not args.bags:
        parser.error("give --manifest and/or --bags")
    return settings, methods


def _bag_pairs(args: argparse.Namespace, frames_dir: Path, loaded: Loaded) -> None:
    """Add the pairs of every ``--bags`` path (ParameterError on a bad -p/--params-file)."""
    from sepfm_ros.evaluation.bags import BagInputs, load_bag_pairs  # needs the ROS packages
    from sepfm_ros.ros.commands.options import given_params_of

    inputs = BagInputs(args.left, args.right, args.image, given_params_of(args))
    for bag in args.bags:
        p, e = load_bag_pairs(bag, frames_dir, inputs)
        loaded.pairs += p
        loaded.errors += e
        if not p:
            loaded.unusable_bags.append(str(bag))


def _load(args: argparse.Namespace, cache_dir: Path | None) -> Loaded:
    """The pairs, load errors and GT cameras of the manifest and the bags (ManifestError,
    ValueError on unusable input)."""
    loaded = Loaded()
    if args.manifest is not None:
        loaded.pairs, loaded.errors = load_manifest(args.manifest, args.root)
        loaded.cameras = load_cameras(
            args.cameras or Path(args.manifest).parent / "cameras.json",
            args.root or Path(args.manifest).parent,
        )
    if args.bags:
        _bag_pairs(args, (cache_dir or args.out) / "bag_frames", loaded)
    return loaded


def _evaluate(args: argparse.Namespace, pairs: list[PairSpec], methods, cache, loaded) -> tuple:
    """Run every method on every pair with every seed, with a progress bar; (result, s)."""
    from tqdm import tqdm

    config = EvalConfig(args.threshold, args.confidence, tuple(args.seeds), args.baseline)
    total = len(pairs) * len(methods) * len(config.seeds)
    print(
        f"sepfm_ros eval: {len(pairs)} pairs x {len(methods)} methods x {len(config.seeds)} "
        f"seeds = {total} runs ({len(loaded.errors)} pairs or bags rejected while loading)",
        file=sys.stderr,
    )
    t0 = time.perf_counter()
    with tqdm(
        total=total, unit="run", disable=args.no_progress, file=sys.stderr, dynamic_ncols=True
    ) as bar:

        def progress(steps: int, pair_id: str) -> None:
            bar.set_postfix_str(pair_id, refresh=False)
            bar.update(steps)

        res = evaluate(
            pairs,
            methods,
            cache,
            config,
            errors=loaded.errors,
            progress=progress,
            cameras=loaded.cameras,
        )
    return res, time.perf_counter() - t0


def main(argv: list[str]) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    settings, methods = _checked(parser, args)
    cache_dir = None if str(args.cache).lower() == "none" else args.cache
    try:
        loaded = _load(args, cache_dir)
    except (ManifestError, ValueError) as exc:
        print(f"sepfm_ros eval: {exc}", file=sys.stderr)
        return 2
    pairs = select_pairs(loaded.pairs, args.scenes, args.max_pairs)
    res, elapsed = _evaluate(args, pairs, methods, MatchesCache(cache_dir, settings), loaded)
    command = "sepfm_ros eval " + shlex.join(argv)
    return _report(args, res, command, elapsed, len(pairs), loaded.unusable_bags)


def _report(args, res, command: str, elapsed: float, n_pairs: int, unusable_bags) -> int:
    """Write the report (and the README table); the exit code."""
    notes = (
        f"Run time: {elapsed:.0f} s for {len(res.runs)} runs on this machine "
        f"(including matching uncached pairs)."
    )
    if res.interrupted:
        notes = (
            f"**Interrupted** after {len(res.pairs)} of {n_pairs} pairs: the tables cover "
            f"those pairs only. {notes}"
        )
    report = write_report(res, args.out, command=command, notes=notes)
    if res.interrupted:
        print(f"sepfm_ros eval: interrupted; partial report: {report}", file=sys.stderr)
        return 130
    if args.readme is not None:
        try:
            update_readme(args.readme, res, command)
        except (OSError, ValueError) as exc:
            print(f"sepfm_ros eval: could not update {args.readme}: {exc}", file=sys.stderr)
            return 2
    print(
        f"sepfm_ros eval: {len(res.pairs)} pairs evaluated, {len(res.errors)} not "
        f"evaluable, {elapsed:.0f} s; report: {report}",
        file=sys.stderr,
    )
    for e in res.errors:
        print(f"  {e.pair_id}: {e.message}", file=sys.stderr)
    if unusable_bags:
        print(
            f"sepfm_ros eval: error: no pair from --bags {', '.join(unusable_bags)} (the reasons "
            "are above)",
            file=sys.stderr,
        )
        return 1
    return 0 if res.pairs else 1
