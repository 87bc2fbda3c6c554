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

import numpy as np
import pytest

from sepfm_ros.demo import bundled_bags_dir, isolate_ros_environment, replay_through_node
from sepfm_ros.ros.make_bag import make_bag, shared_frames
from sepfm_ros.ros.process import parse_params, run_process
from sepfm_ros.ros.results import read_results

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
    no_f = [(r.stamp_ns, r.info.get("status")) for r in live_results if r.F is None]
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
        o = offline[r.stamp_ns]
        assert (r.F is None) == (o.F is None)
        if r.F is not None:
            np.testing.assert_allclose(r.F, o.F, rtol=0, atol=1e-12)
        assert r.cloud is not None and o.cloud is not None
        assert np.array_equal(r.cloud, o.cloud)  # same matches, errors, inlier and line flags
        for key in ("matches", "inliers", "hypotheses", "stage1_hypotheses", "status"):
            assert r.info[key] == o.info[key], key
    return live_results


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
