"""Replay tests: bags through the live node over real DDS (loopback), recorded back.

Every bundled bag and bags built at test time from ../shared/data (KITTI stereo, KITTI motion,
templeRing motion) are replayed at their recorded rate (real time) into a ``sepfm`` node
subprocess, its outputs recorded into a bag, and checked: an F for at least 95% of the frame pairs,
median error against ground truth below 1 px (per bag: the median over frames of the median
GT-inlier error), and the live results equal to ``process`` on the same bag with the same seed.
"""

from __future__ import annotations

import math
import os

import cv2
import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.highlevel import AnyReader
from sensor_msgs.msg import CompressedImage

from sepfm_msgs.msg import TwoViewEstimate
from sepfm_ros.demo import bundled_bags_dir, isolate_ros_environment, replay_through_node
from sepfm_ros.ros.bags.results import MATCH_TABLE_DTYPE, read_results
from sepfm_ros.ros.bags.synthesis import (
    SourceFrame,
    bag_messages,
    make_bag,
    shared_frames,
    synthetic_frames,
)
from sepfm_ros.ros.bags.writer import BagWriter
from sepfm_ros.ros.offline.process import run_process
from sepfm_ros.ros.session.parameters import parse_params

SEED = 7
# 20 pairs each: "an F for at least 95 % of frame pairs" then tolerates one lost pair (with 10
# it would demand all; on loaded CI machines the first KITTI stereo pair was occasionally lost)
SHARED_BAGS = {  # name -> (sequence, first frame, frames)
    "kitti_stereo": ("kitti_stereo", 0, 20),
    "kitti_motion": ("kitti_motion", 20, 21),
    "templeRing": ("templeRing", 5, 21),
}
BAG_RATE_HZ = 1.0  # KITTI pairs take 110-250 ms (more under load) on shared 2-core machines


@pytest.fixture(scope="module")
def ros_env(ros_domain_id):
    isolate_ros_environment()
    assert os.environ["ROS_DOMAIN_ID"] == str(ros_domain_id)
    return ros_domain_id


def _check_live_equals_process(bag, tmp_path, median_limit_px: float):
    params = [f"seed:={SEED}"]
    live = replay_through_node(
        bag,
        tmp_path / "live",
        params,
        rate=1.0,
        debug_image=False,
        progress=False,
        log_path=tmp_path / "node.log",
    )
    offline_bag = tmp_path / "offline"
    done, expected = run_process(bag, offline_bag, parse_params(params), progress=False)
    assert done == expected == live.expected_pairs
    live_results = read_results(live.output, gt_bag=bag)
    offline = {r.stamp_ns: r for r in read_results(offline_bag)}
    log = (tmp_path / "node.log").read_text()

    with_f = [r for r in live_results if r.F is not None]
    unanswered = sorted(set(offline) - {r.stamp_ns for r in live_results})
    no_f = [(r.stamp_ns, r.status) for r in live_results if r.F is None]
    assert len(with_f) >= math.ceil(0.95 * expected), (
        f"live F for {len(with_f)} of {expected} pairs; unanswered stamps {unanswered}; "
        f"answered without F {no_f}\n{log[-3000:]}"
    )
    errors = [r.error_px for r in with_f]
    assert all(r.F_gt is not None for r in with_f)
    assert np.nanmedian(errors) < median_limit_px, errors

    # live == offline for every stamp the node answered
    assert set(r.stamp_ns for r in live_results) <= set(offline)
    for r in live_results:
        assert_same_answer(r, offline[r.stamp_ns])
    return live_results


# Fields derived from F in floating point: the node (numpy's BLAS on one thread) and ``process``
# may round F differently in its last bits (F agrees to 1e-9), so these agree to a relative 1e-6;
# the pose's rotation (an SVD of E, whose two equal singular values make it ill-conditioned) to
# 1e-4 degrees.
DERIVED_FLOATS = ("inlier_error_px", "log10_nfa", "line_a", "line_b")
ROTATION_TOLERANCE_DEG = 1e-4


def answer_fields(msg) -> dict:
    """Everything of a TwoViewEstimate but F, the timings (which differ run to run), the pose
    and the floats derived from F (:data:`DERIVED_FLOATS`, compared by :func:`derived_floats`)."""
    return {
        name: getattr(msg, name)
        for name in msg.get_fields_and_field_types()
        if name not in ("f", "timings", "pose", "rotation_deg", *DERIVED_FLOATS)
    }


def derived_floats(msg) -> np.ndarray:
    """:data:`DERIVED_FLOATS` of a TwoViewEstimate as one float array (NaN where absent)."""
    return np.concatenate([np.ravel(np.asarray(getattr(msg, n), float)) for n in DERIVED_FLOATS])


def assert_same_answer(live, offline) -> None:
    """The node's answer for a pair equals ``process``'s: every field (status code and text,
    failure kind, counts, line pair, sizes, stamps), F to 1e-9 and every match."""
    assert live.estimate is not None and offline.estimate is not None
    assert answer_fields(live.estimate) == answer_fields(offline.estimate), live.stamp_ns
    np.testing.assert_allclose(
        derived_floats(live.estimate), derived_floats(offline.estimate), rtol=1e-6, atol=1e-9
    )  # NaN where both are NaN compares equal
    np.testing.assert_allclose(
        live.estimate.rotation_deg,
        offline.estimate.rotation_deg,
        rtol=0,
        atol=ROTATION_TOLERANCE_DEG,
    )
    assert (live.F is None) == (offline.F is None)
    if live.F is not None:
        np.testing.assert_allclose(live.F, offline.F, rtol=0, atol=1e-9)
    assert live.match_rows is not None and offline.match_rows is not None
    # same matches, inlier and line flags; errors under F to a relative 1e-6 (NaN without F)
    for name in MATCH_TABLE_DTYPE.names:
        a, b = live.match_rows[name], offline.match_rows[name]
        if name == "error_px":
            np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-9, err_msg=name)
        else:
            np.testing.assert_array_equal(a, b, name)


@pytest.mark.parametrize("name", ["synthetic_stereo", "synthetic_motion"])
def test_bundled_bag_live_equals_process(name, tmp_path, ros_env):
    bag = bundled_bags_dir() / name
    _check_live_equals_process(bag, tmp_path, median_limit_px=1.0)


@pytest.mark.parametrize("name", sorted(SHARED_BAGS))
def test_shared_bag_live_equals_process(name, tmp_path, shared_data, ros_env):
    sequence, first, count = SHARED_BAGS[name]
    mode, frames = shared_frames(shared_data, sequence)
    bag = tmp_path / f"{name}_bag"
    make_bag(bag, mode, frames[first : first + count], rate_hz=BAG_RATE_HZ, encoding="mono8")
    _check_live_equals_process(bag, tmp_path, median_limit_px=1.0)


def write_bag_with_bad_pairs(out, rate_hz: float = 1.0) -> None:
    """A compressed motion bag of 7 rendered frames: frame 2 is JPEG-framed garbage (passes the
    node's field check, fails to decode), frame 4 a truncated JPEG (skipped before pairing by
    the node and ``process``), frames 5 and 6 half size. Pairs: (0, 1) and (5, 6) good, (1, 2)
    and (2, 3) undecodable, (3, 5) a frame-size change."""
    _, frames = synthetic_frames("motion", 7, seed=SEED)
    frames = [SourceFrame(None, f.load(), None) for f in frames]  # no ground truth, no calib
    for k in (5, 6):
        (img,) = frames[k].load()
        half = cv2.resize(img, (img.shape[1] // 2, img.shape[0] // 2))
        frames[k] = SourceFrame(None, (half,), None)
    broken = {2: b"\xff\xd8\xff\xe0 not a JPEG inside \xff\xd9", 4: b"\xff\xd8\xff truncated"}
    with BagWriter(out, flush_interval_s=None) as writer:
        for k, (topic, msgtype, stamp, data) in enumerate(
            bag_messages("motion", frames, rate_hz, "compressed", compressed_format="jpeg")
        ):
            if k in broken:
                msg = deserialize_message(data, CompressedImage)
                msg.data = broken[k]
                data = serialize_message(msg)
            writer.add_topic(topic, msgtype)
            writer.write(topic, stamp, data)


def test_node_and_process_answer_bad_pairs_alike(tmp_path, ros_env):
    """One bag both ways, live node over DDS and ``process``, at a fixed seed: the same answer
    pair by pair, including the failure records of undecodable pairs and of a frame-size change,
    and the same frame skipped before pairing (no pair answered differently, none left out)."""
    bag = tmp_path / "bad_pairs"
    write_bag_with_bad_pairs(bag)
    params = [f"seed:={SEED}"]
    live = replay_through_node(
        bag, tmp_path / "live", params, debug_image=False, progress=False,
        log_path=tmp_path / "node.log",
    )  # fmt: skip
    done, expected = run_process(bag, tmp_path / "offline", parse_params(params), progress=False)
    assert done == expected == 5
    live_results = read_results(live.output)
    offline = read_results(tmp_path / "offline")
    log = (tmp_path / "node.log").read_text()
    assert [r.stamp_ns for r in live_results] == [r.stamp_ns for r in offline], log[-3000:]
    for r, o in zip(live_results, offline, strict=True):
        assert_same_answer(r, o)
    codes = [r.estimate.status for r in offline]
    kinds = [r.estimate.bad_input_kind for r in offline]
    bad = TwoViewEstimate.STATUS_BAD_INPUT
    assert codes[1:4] == [bad, bad, bad] and bad not in (codes[0], codes[4])
    assert kinds[0] == kinds[4] == "" and kinds[1] == kinds[2] != ""
    assert kinds[3] == "size_change"
    assert offline[0].F is not None and offline[4].F is not None
    change = offline[3].estimate
    assert change.width_b == change.width_a // 2 and not change.has_f
    assert all(len(offline[k].match_rows) == 0 for k in (1, 2, 3))
    assert "truncated_compressed" in log  # frame 4: skipped by the node too
    # the recorded answers carry their definitions: plain rosbags reads them (types from the bag)
    with AnyReader([live.output]) as reader:
        conns = [c for c in reader.connections if c.topic == "/sepfm/estimate"]
        recorded = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages(conns)]
    assert [int(m.status) for m in recorded] == codes
    assert [m.bad_input_kind for m in recorded] == kinds
