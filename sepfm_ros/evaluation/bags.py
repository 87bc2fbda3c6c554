"""Pairs with ground truth from bags, for ``sepfm_ros eval --bags``.

Two kinds of bag are read (see :mod:`sepfm_ros.ros.bags.synthesis` and
:mod:`sepfm_ros.ros.offline.process`):

- an *input bag* with image topics (the ``--left``/``--right`` or ``--image`` topics when given,
  else picked from the bag as ``process`` does, see :mod:`sepfm_ros.ros.bags.inputs`) and
  ``/ground_truth/fundamental``: the pairs are the ones ``process`` forms
  (:func:`sepfm_ros.ros.bags.pairing.iter_pairs` with the session's pairing, at the node
  parameters given by ``-p``/``--params-file``), each
  scored against the GT F with the pair's stamp. The decoded frames are written as PNG files into
  a folder (under the matches cache), so matches are cached by image content like manifest pairs.
- a bag written by ``process`` (``/sepfm/...`` outputs plus the copied ground truth): the pairs are
  the node's own matches (``~/matches``) with the GT F of the same stamp, as points entries.

Bags are rosbag2 (sqlite3, mcap) or ROS 1 ``.bag`` files. Bag problems (missing, corrupt, no
ground truth, no images) become one :class:`PairError` per bag,
and a pair without ground truth or with an undecodable image one per pair; nothing raises. This
module needs the ROS message packages (rclpy); the evaluation imports it only for ``--bags``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from sepfm_ros.evaluation.manifest import PairDataError, PairError, PairSpec, parse_fundamental
from sepfm_ros.ros.bags.errors import BagError
from sepfm_ros.ros.bags.inputs import detect_inputs
from sepfm_ros.ros.bags.pairing import iter_pairs, pairing_slop_ns, validate_inputs
from sepfm_ros.ros.bags.reader import BAG_SUFFIXES, BagReader
from sepfm_ros.ros.bags.results import (
    OUTPUT_NAMESPACE,
    output_topics,
    read_ground_truth,
    read_results,
    run_label,
)
from sepfm_ros.ros.bags.types import GROUND_TRUTH_TOPIC, format_stamp
from sepfm_ros.ros.msgs.headers import stamp_ns
from sepfm_ros.ros.msgs.image_conversion import ImageDecodeError, pair_to_numpy
from sepfm_ros.ros.session.parameters import GivenParams, ParameterError, given_params
from sepfm_ros.ros.session.session import Session


def is_bag(path: Path) -> bool:
    """A rosbag2 directory (with metadata.yaml) or a bare .mcap / .db3 / ROS 1 .bag file."""
    if path.is_dir():
        return (path / "metadata.yaml").is_file()
    return path.suffix in BAG_SUFFIXES and path.is_file()


def find_bags(path: Path) -> list[Path]:
    """``path`` itself when it is a bag, else the bags directly inside it (sorted)."""
    if is_bag(path):
        return [path]
    if path.is_dir():
        return sorted(p for p in path.iterdir() if is_bag(p))
    return []


def _input_bag_pairs(
    bag: Path, reader: BagReader, frames_dir: Path, inputs_of: BagInputs
) -> tuple[list[PairSpec], list[PairError]]:
    spec = detect_inputs(reader, None, inputs_of.left, inputs_of.right, inputs_of.image)
    given = inputs_of.params or given_params()
    params = given.values
    inputs = validate_inputs(reader, spec)
    slop_given = "sync_slop_s" in given.given
    slop_ns = pairing_slop_ns(params, inputs.stamps[spec.topics[0]], slop_given)
    try:
        session = Session(params, spec.mode == "stereo", spec.topics)
    except ParameterError as err:
        raise BagError(str(err)) from None
    gt = read_ground_truth(bag)
    pairs, errors = [], []
    out = frames_dir / bag.name
    out.mkdir(parents=True, exist_ok=True)
    for job in iter_pairs(reader, spec, session, slop_ns):
        stamp = stamp_ns(job.header.stamp)
        run = run_label(job.run)  # a looped bag's later passes get ids of their own
        pid = f"{bag.name}@{format_stamp(stamp)}{run}"
        try:
            if stamp not in gt:
                raise PairDataError(f"no {GROUND_TRUTH_TOPIC} message with stamp {stamp} ns")
            F = parse_fundamental(gt[stamp])
            paths = []
            images = pair_to_numpy(job.msg_a, job.msg_b, "mono8")  # one contrast for the pair
            for tag, img in zip(("a", "b"), images, strict=True):
                p = out / f"{stamp}{run}_{tag}.png"
                if not cv2.imwrite(str(p), img):
                    raise PairDataError(f"cannot write decoded frame {p}")
                paths.append(p)
        except (PairDataError, ImageDecodeError) as exc:
            errors.append(PairError(pid, bag.name, f"bag {bag}: {exc}"))
            continue
        pairs.append(PairSpec(pid, bag.name, F, img_a=paths[0], img_b=paths[1], kind=spec.mode))
    if not pairs and not errors:
        why = inputs.no_pairs_reason(spec, int(params["frame_gap"]), slop_ns, None)
        errors.append(PairError(bag.name, bag.name, f"bag {bag}: {why}"))
    return pairs, errors


def _processed_bag_pairs(bag: Path) -> tuple[list[PairSpec], list[PairError]]:
    pairs, errors = [], []
    for fr in read_results(bag):
        pid = f"{bag.name}@{format_stamp(fr.stamp_ns)}{fr.run_label}"
        pts_a, pts_b = fr.pts()
        est = fr.estimate
        size_a = (int(est.width_a), int(est.height_a)) if est is not None else (0, 0)
        size_b = (int(est.width_b), int(est.height_b)) if est is not None else (0, 0)
        try:
            if fr.F_gt is None:
                raise PairDataError(f"no {GROUND_TRUTH_TOPIC} message with this stamp")
            if min(size_a) <= 0 or min(size_b) <= 0:
                raise PairDataError("no image size in the estimate (a failure record?)")
            F = parse_fundamental(fr.F_gt)
        except PairDataError as exc:
            errors.append(PairError(pid, bag.name, f"bag {bag}: {exc}"))
            continue
        pairs.append(
            PairSpec(
                pid,
                bag.name,
                F,
                pts_a=np.ascontiguousarray(pts_a),
                pts_b=np.ascontiguousarray(pts_b),
                size_a=size_a,
                size_b=size_b,
                kind="processed",
            )
        )
    return pairs, errors


@dataclass(frozen=True)
class BagInputs:
    """How input bags are read: their topics (None: picked from each bag) and the node's
    parameters, whose pairing (the session's) forms the pairs (None: the defaults)."""

    left: str | None = None
    right: str | None = None
    image: str | None = None
    params: GivenParams | None = None


def load_bag_pairs(
    path: str | Path, frames_dir: str | Path, inputs_of: BagInputs | None = None
) -> tuple[list[PairSpec], list[PairError]]:
    """Pairs with ground truth from a bag or a folder of bags.

    Args:
        path: a bag (directory, .mcap/.db3 or ROS 1 .bag) or a folder holding bags.
        frames_dir: where decoded frames of input bags are written (one subfolder per bag).
        inputs_of: the input topics and parameters of input bags.
    Returns:
        (pairs, errors): errors name the bag (or pair) and the problem.
    """
    path = Path(path)
    bags = find_bags(path)
    if not bags:
        return [], [PairError(path.name, path.name, f"no bag found at {path}")]
    pairs: list[PairSpec] = []
    errors: list[PairError] = []
    outputs = set(output_topics(OUTPUT_NAMESPACE).values())
    for bag in bags:
        try:
            with BagReader(bag) as reader:
                if GROUND_TRUTH_TOPIC not in reader.topics:
                    raise BagError(f"no {GROUND_TRUTH_TOPIC} topic: nothing to score against")
                processed = bool(outputs & set(reader.topics))
                if not processed:
                    p, e = _input_bag_pairs(bag, reader, Path(frames_dir), inputs_of or BagInputs())
            if processed:
                p, e = _processed_bag_pairs(bag)
        except BagError as exc:
            errors.append(PairError(bag.name, bag.name, f"bag {bag}: {exc}"))
            continue
        pairs += p
        errors += e
    return pairs, errors
