"""``sepfm_ros rectify`` over real DDS.

- With a test publisher: a real stereo pair (KITTI, right image rotated 2 degrees) and the
  TwoViewEstimate + MatchArray of the pipeline's estimate on it; the rectifier publishes
  left/right image_rect with the inputs' stamps and sizes, rows aligned (SIFT matches between
  the two published images at under 0.5 px vertical disparity), holds its homographies through
  bad estimates, and counts bad input without stopping.
- End to end: the sepfm node and the rectifier on the same image topics, at their defaults.
"""

from __future__ import annotations

import json
import sys
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

pytest.importorskip("rclpy")
sepfm_msgs = pytest.importorskip("sepfm_msgs.msg")

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from ros_helpers import RELIABLE, NodeProcess, Ros, header, image_msg, next_stamp  # noqa: E402
from sensor_msgs.msg import Image  # noqa: E402

from sepfm_ros.pipeline.pipeline import Pipeline, PipelineResult  # noqa: E402
from sepfm_ros.pipeline.rectification import rectify_uncalibrated  # noqa: E402
from sepfm_ros.ros.msgs.fundamental import fundamental_field  # noqa: E402
from sepfm_ros.ros.msgs.headers import stamp_ns  # noqa: E402
from sepfm_ros.ros.msgs.image_conversion import image_to_numpy  # noqa: E402
from sepfm_ros.ros.session.answer import AnswerSettings, PairHeaders, estimate_message, match_array  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
import bench_rectify  # noqa: E402

TwoViewEstimate, MatchArray = sepfm_msgs.TwoViewEstimate, sepfm_msgs.MatchArray
NAME = "rectify_test"
TIMEOUT = 60.0  # s; the machine is shared
TARGET_PX = 0.5


def estimate_messages(
    result: PipelineResult, stamp: int, status: int | None = None
) -> tuple[TwoViewEstimate, MatchArray]:
    """The TwoViewEstimate and MatchArray the sepfm node publishes for ``result`` (its answer
    path), stamped ``stamp``; ``status`` overrides the estimate's status."""
    h = header(stamp)
    headers = PairHeaders(h, h, h)
    settings = AnswerSettings.of(bench_rectify.CONFIG, publish_unreliable=False)
    msg = estimate_message(headers, result, settings, result.coordinates, None, False)
    if status is not None:
        msg.status, msg.status_text = status, "forced by the test"
    return msg, match_array(headers, result)


def row_disparity(img_a: np.ndarray, img_b: np.ndarray) -> float:
    """Median |v_a - v_b| (px) of SIFT matches (ratio 0.7) between two images."""
    sift = cv2.SIFT_create(2000)
    ka, da = sift.detectAndCompute(img_a, None)
    kb, db = sift.detectAndCompute(img_b, None)
    pairs = cv2.BFMatcher().knnMatch(da, db, k=2)
    good = [m for m, n in pairs if m.distance < 0.7 * n.distance]
    assert len(good) > 100
    dv = [ka[m.queryIdx].pt[1] - kb[m.trainIdx].pt[1] for m in good]
    return float(np.median(np.abs(dv)))


class Listener:
    """The test's subscriptions to the rectifier's outputs and its /diagnostics status."""

    def __init__(self, ros: Ros) -> None:
        self.lock = threading.Lock()
        self.rect: dict[str, dict[int, Image]] = {"left": {}, "right": {}}
        self.health: list[dict[str, str]] = []
        for side in ("left", "right"):
            ros.node.create_subscription(
                Image, f"/{side}/image_rect", self._keep(self.rect[side]), RELIABLE
            )
        ros.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, RELIABLE)

    def _keep(self, store: dict[int, Image]):
        def callback(msg: Image) -> None:
            with self.lock:
                store[stamp_ns(msg.header.stamp)] = msg

        return callback

    def _on_diag(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name == f"/{NAME}: rectify":
                with self.lock:
                    self.health.append({kv.key: kv.value for kv in status.values})

    def wait_pair(self, left_stamp: int, right_stamp: int) -> tuple[Image, Image]:
        deadline = time.monotonic() + TIMEOUT
        while time.monotonic() < deadline:
            with self.lock:
                left = self.rect["left"].get(left_stamp)
                right = self.rect["right"].get(right_stamp)
            if left is not None and right is not None:
                return left, right
            time.sleep(0.05)
        raise AssertionError(f"no rectified pair for stamps {left_stamp}, {right_stamp}")

    def wait_count(self, key: str, at_least: int) -> dict[str, str]:
        deadline = time.monotonic() + TIMEOUT
        while time.monotonic() < deadline:
            with self.lock:
                last = self.health[-1] if self.health else {}
            if int(last.get(key, "0")) >= at_least:
                return last
            time.sleep(0.1)
        raise AssertionError(f"/diagnostics never counted {at_least} {key}: {last}")


@pytest.fixture(scope="module")
def rotated_pair(shared_data):
    """(case, pipeline result) of a KITTI stereo pair with the right image rotated 2 deg."""
    pairs = json.loads((shared_data / "pairs.json").read_text())
    cams = json.loads((shared_data / "cameras.json").read_text())
    entry = next(p for p in pairs if p["baseline"] == "stereo" and p["scene"] == "kitti_seq2")
    case = bench_rectify.rotated_case(entry, cams, 2.0)
    result = Pipeline(bench_rectify.CONFIG).process(case.image_a, case.image_b)
    assert result.ok, result.estimate.status
    return case, result


def test_rectifier_over_dds(rotated_pair, ros_domain_id, tmp_path):
    case, result = rotated_pair
    ros = Ros()
    listener = Listener(ros)
    pubs = {
        "left": ros.node.create_publisher(Image, "/cam/left/image_raw", RELIABLE),
        "right": ros.node.create_publisher(Image, "/cam/right/image_raw", RELIABLE),
        "estimate": ros.node.create_publisher(TwoViewEstimate, "/sepfm/estimate", RELIABLE),
        "matches": ros.node.create_publisher(MatchArray, "/sepfm/matches", RELIABLE),
    }
    proc = NodeProcess(
        NAME, tmp_path, "-p", "diagnostic_updater.period:=0.2",
        "-r", "left/image_raw:=/cam/left/image_raw", "-r", "right/image_raw:=/cam/right/image_raw",
        "-r", "left/image_rect:=/left/image_rect", "-r", "right/image_rect:=/right/image_rect",
        command="rectify",
    )  # fmt: skip
    try:
        deadline = time.monotonic() + TIMEOUT
        while any(p.get_subscription_count() == 0 for p in pubs.values()):
            assert proc.proc.poll() is None, proc.output()
            assert time.monotonic() < deadline, f"rectifier not subscribed:\n{proc.output()}"
            time.sleep(0.1)

        def send_images(left: np.ndarray, right: np.ndarray) -> tuple[int, int]:
            s = next_stamp()
            pubs["left"].publish(image_msg(left, s))
            pubs["right"].publish(image_msg(right, s + 1_000_000))  # 1 ms later: paired
            return s, s + 1_000_000

        # before any estimate: counted as waiting, nothing published
        send_images(case.image_a, case.image_b)
        listener.wait_count("waiting", 1)
        assert not listener.rect["left"]

        # a real estimate, then a pair: rectified with the inputs' stamps and sizes
        est, arr = estimate_messages(result, next_stamp())
        pubs["matches"].publish(arr)  # the matches may come first
        pubs["estimate"].publish(est)
        listener.wait_count("estimates_used", 1)
        s_left, s_right = send_images(case.image_a, case.image_b)
        left, right = listener.wait_pair(s_left, s_right)
        h, w = case.image_a.shape
        for msg in (left, right):
            assert (msg.width, msg.height, msg.encoding) == (w, h, "mono8")
        out_a, out_b = image_to_numpy(left), image_to_numpy(right)
        inl = result.estimate.inliers
        m = result.matches
        expected = rectify_uncalibrated(
            result.estimate.F, m.pts_a[inl], m.pts_b[inl], result.size_a, result.size_b
        ).warp(case.image_a, case.image_b)
        assert np.array_equal(out_a, expected[0]) and np.array_equal(out_b, expected[1])
        assert row_disparity(case.image_a, case.image_b) > 5.0
        assert row_disparity(out_a, out_b) < TARGET_PX

        # a bad estimate (not ok) is refused and the homographies are held
        bad, bad_arr = estimate_messages(result, next_stamp(), TwoViewEstimate.STATUS_DEGENERATE)
        pubs["estimate"].publish(bad)
        pubs["matches"].publish(bad_arr)
        listener.wait_count("refused_estimate_not_ok", 1)
        # an ok estimate with a rank-1 F: refused as degenerate
        rank1, rank1_arr = estimate_messages(result, next_stamp())
        rank1.f = fundamental_field(np.outer([1.0, 2.0, 3.0], [0.5, -1.0, 2.0]))
        pubs["estimate"].publish(rank1)
        pubs["matches"].publish(rank1_arr)
        listener.wait_count("refused_degenerate_f", 1)
        s_left, s_right = send_images(case.image_a, case.image_b)
        left, _ = listener.wait_pair(s_left, s_right)
        assert np.array_equal(image_to_numpy(left), expected[0])

        # bad images: a short buffer and another size are counted, the node keeps serving
        broken = image_msg(case.image_a, next_stamp())
        broken.data = bytes(broken.data)[:100]
        pubs["left"].publish(broken)
        pubs["right"].publish(image_msg(case.image_b, stamp_ns(broken.header.stamp)))
        listener.wait_count("short_data", 1)
        send_images(case.image_a[:200], case.image_b[:200])
        listener.wait_count("size_change", 1)
        s_left, s_right = send_images(case.image_a, case.image_b)
        listener.wait_pair(s_left, s_right)
        health = listener.wait_count("published", 3)
        assert int(health["estimates_used"]) == 1
        assert not [k for k in health if k.startswith("internal_")], health
        assert proc.proc.poll() is None
    except AssertionError as err:
        raise AssertionError(f"{err}\nrectifier's output:\n{proc.output()}") from None
    finally:
        code = proc.stop()
        ros.close()
    assert code == 0, proc.output()


def test_rectifier_behind_the_sepfm_node(rotated_pair, ros_domain_id, tmp_path):
    """The real node's ~/estimate and ~/matches drive the rectifier: the same image stream in,
    rectified pairs out with the inputs' stamps, rows aligned."""
    case, _ = rotated_pair
    ros = Ros()
    listener = Listener(ros)
    pubs = {
        "left": ros.node.create_publisher(Image, "/cam/left/image_raw", RELIABLE),
        "right": ros.node.create_publisher(Image, "/cam/right/image_raw", RELIABLE),
    }
    inputs = ("-r", "left/image_raw:=/cam/left/image_raw",
              "-r", "right/image_raw:=/cam/right/image_raw")  # fmt: skip
    node = NodeProcess("sepfm_e2e", tmp_path, "-p", "mode:=stereo", *inputs)
    rect = NodeProcess(
        NAME, tmp_path, *inputs, "-p", "diagnostic_updater.period:=0.2",
        "-r", "sepfm/estimate:=/sepfm_e2e/estimate", "-r", "sepfm/matches:=/sepfm_e2e/matches",
        "-r", "left/image_rect:=/left/image_rect", "-r", "right/image_rect:=/right/image_rect",
        command="rectify",
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 3 * TIMEOUT  # the node loads its kernels first
        while any(p.get_subscription_count() < 2 for p in pubs.values()) or (
            ros.node.count_subscribers("/sepfm_e2e/estimate") == 0
        ):
            for proc in (node, rect):
                assert proc.proc.poll() is None, proc.output()
            assert time.monotonic() < deadline, "the two nodes did not come up"
            time.sleep(0.1)
        got = None
        while got is None and time.monotonic() < deadline:
            s = next_stamp()
            pubs["left"].publish(image_msg(case.image_a, s))
            pubs["right"].publish(image_msg(case.image_b, s))
            end = time.monotonic() + 2.0
            while got is None and time.monotonic() < end:
                with listener.lock:
                    if s in listener.rect["left"] and s in listener.rect["right"]:
                        got = listener.rect["left"][s], listener.rect["right"][s]
                time.sleep(0.05)
        assert got is not None, "no rectified pair"
        left, right = got
        h, w = case.image_a.shape
        assert (left.width, left.height) == (right.width, right.height) == (w, h)
        assert left.header.frame_id == right.header.frame_id == "cam"
        assert row_disparity(image_to_numpy(left), image_to_numpy(right)) < TARGET_PX
    except AssertionError as err:
        raise AssertionError(
            f"{err}\nnode:\n{node.output()[-3000:]}\nrectifier:\n{rect.output()[-3000:]}"
        ) from None
    finally:
        codes = (node.stop(), rect.stop())
        ros.close()
    assert codes == (0, 0)
