"""One session for every way in: a calibrated stereo bag with non-default parameters gives the
same answer pair by pair through the live node (replayed over DDS), ``process``,
``calibration_check`` and ``audit`` (one slice): the same F, inliers and calibration level.

The parameters (SIFT, 1500 features, a 1.5 px threshold, seed 3) are not the defaults, so a path
that ignores them (``calibration_check`` built its own default pipeline before the session)
fails here.
"""

from __future__ import annotations

import io
import math
import os
from pathlib import Path

import numpy as np
import pytest

from sepfm_ros.demo import isolate_ros_environment, replay_through_node
from sepfm_ros.fleet.records import InputChoice, SliceResult, SliceTask
from sepfm_ros.ros.bags.results import read_calibration_checks, read_results
from sepfm_ros.ros.bags.synthesis import make_bag, shared_frames
from sepfm_ros.ros.offline.audit_slices import audit_slice, inspect_bag
from sepfm_ros.ros.offline.process import run_process
from sepfm_ros.ros.offline.rig_check import CheckRequest, run_check
from sepfm_ros.ros.session.parameters import given_params

PARAMS = ["features:=sift", "max_features:=1500", "threshold_px:=1.5", "seed:=3"]
FRAMES = 8
LEVELS = {0: "OK", 1: "WARN", 2: "ERROR", 3: "STALE"}


@pytest.fixture(scope="module")
def ros_env(ros_domain_id):
    isolate_ros_environment()
    assert os.environ["ROS_DOMAIN_ID"] == str(ros_domain_id)
    return ros_domain_id


@pytest.fixture(scope="module")
def kitti_bag(shared_data, tmp_path_factory) -> Path:
    """KITTI stereo frames with their camera_info (a calibrated rig), one pair per second."""
    mode, frames = shared_frames(shared_data, "kitti_stereo")
    bag = tmp_path_factory.mktemp("paths") / "kitti"
    make_bag(bag, mode, frames[:FRAMES], rate_hz=1.0)
    return bag


def calibration_levels(bag: Path, namespace: str = "/sepfm") -> list[str]:
    """The ~/calibration_check levels in a bag of the node's outputs, in log-time order."""
    checks = read_calibration_checks(bag, namespace)
    return [LEVELS[int.from_bytes(c.status.level, "little")] for c in checks]


def answers(bag: Path) -> dict[int, tuple[np.ndarray | None, int]]:
    """stamp (ns) -> (F or None, inliers) of a bag of the node's outputs."""
    return {r.stamp_ns: (r.F, int(r.estimate.inliers)) for r in read_results(bag)}


def assert_same_f(a: np.ndarray | None, b: np.ndarray | None, where: str) -> None:
    assert (a is None) == (b is None), where
    if a is not None:
        a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)
        sign = 1.0 if float(np.sum(a * b)) >= 0 else -1.0
        np.testing.assert_allclose(a, sign * b, atol=1e-9, err_msg=where)


def test_node_process_calibration_check_and_audit_answer_alike(kitti_bag, ros_env, tmp_path):
    given = given_params(PARAMS)
    # process
    done, total = run_process(kitti_bag, tmp_path / "process", given.values, progress=False)
    assert done == total == FRAMES
    offline = answers(tmp_path / "process")
    offline_levels = calibration_levels(tmp_path / "process")
    assert len(offline_levels) == FRAMES and "OK" in offline_levels, offline_levels

    # calibration_check
    rows = run_check(CheckRequest(str(kitti_bag), given.values), out=io.StringIO())
    assert [r.stamp_ns for r in rows] == sorted(offline)
    for row, level in zip(rows, offline_levels, strict=True):
        F, inliers = offline[row.stamp_ns]
        assert_same_f(row.F, F, f"calibration_check at {row.stamp_ns}")
        assert row.inliers == inliers and row.status.level_name == level, row

    # audit, one slice spanning the bag
    info = inspect_bag(str(kitti_bag), given.values, InputChoice())
    task = SliceTask(info, 0, 1, info.start_ns, info.end_ns + 1, info.start_ns, given.values)
    result = audit_slice(task)
    assert isinstance(result, SliceResult), result
    assert [p.stamp_ns for p in result.pairs] == sorted(offline)
    for record, level in zip(result.pairs, offline_levels, strict=True):
        F, inliers = offline[record.stamp_ns]
        assert record.has_f == (F is not None) and record.inliers == inliers, record
        assert record.level == level, record

    # the live node, replayed over DDS, on the stamps it answered
    live = replay_through_node(
        kitti_bag, tmp_path / "live", PARAMS, rate=1.0, debug_image=False, progress=False,
        log_path=tmp_path / "node.log",
    )  # fmt: skip
    node = answers(live.output)
    log = (tmp_path / "node.log").read_text()
    assert len(node) >= math.ceil(0.75 * FRAMES), log[-3000:]
    for stamp, (F, inliers) in node.items():
        assert_same_f(F, offline[stamp][0], f"node at {stamp}")
        assert inliers == offline[stamp][1], stamp
    if len(node) == FRAMES:  # the monitor's window saw every pair: the same decisions
        assert calibration_levels(live.output) == offline_levels


def _check_inliers(bag: Path, params: list[str]) -> list[int]:
    """calibration_check's inlier count per pair on the first two pairs of ``bag``."""
    records = run_check(
        CheckRequest(str(bag), given_params(params).values, max_pairs=2), out=io.StringIO()
    )
    assert len(records) == 2
    return [r.inliers for r in records]


@pytest.fixture(scope="module")
def default_inliers(kitti_bag) -> list[int]:
    return _check_inliers(kitti_bag, [])


@pytest.mark.parametrize(
    "params",
    [
        # features:=sift changes calibration_check's matches as it changes the node's
        PARAMS,
        # KITTI's 1241 px frames detected downscaled by 2, as the node would detect them
        ["feature_max_width:=640"],
    ],
    ids=["features", "feature_max_width"],
)
def test_calibration_check_takes_the_nodes_pipeline_parameters(kitti_bag, default_inliers, params):
    """A node parameter of the pipeline gives calibration_check other inlier counts on the same
    pairs than the defaults (ORB, full size)."""
    assert _check_inliers(kitti_bag, params) != default_inliers


def test_session_answers_wide_frames_in_full_resolution_pixels(shared_data_lines):
    """A 1536x1024 camera with ``feature_max_width:=1280``: detected at 768x512, answered in
    the frames' own pixels (sizes, matches) by the one answer path of every entry point."""
    import cv2
    from std_msgs.msg import Header

    from sepfm_ros.ros.msgs.image_conversion import numpy_to_image
    from sepfm_ros.ros.session.answer import PairHeaders
    from sepfm_ros.ros.session.session import Session

    frames = [
        cv2.imread(str(shared_data_lines / f"fountain-P11/000{k}.jpg"), cv2.IMREAD_GRAYSCALE)
        for k in (0, 1)
    ]
    values = given_params(["mode:=motion", "feature_max_width:=1280"]).values
    session = Session(values, stereo=False, topics=["/image_raw"])
    header = Header(frame_id="camera")
    msgs = [numpy_to_image(f, "mono8", header) for f in frames]
    answer = session.answer(PairHeaders(header, header, header), *msgs, keys=(1, 2))
    assert answer.result is not None and answer.result.ok
    assert (answer.estimate.width_a, answer.estimate.height_a) == (1536, 1024)
    u_a = np.array([m.u_a for m in answer.matches.matches])
    assert len(u_a) >= 50 and u_a.max() > 1000  # full-size pixels, not 768 px wide ones
