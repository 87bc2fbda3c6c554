"""The live node's corrected calibration at its edges, over real DDS (helpers of
test_node_corrected.py: KITTI's stereo frames, the right image turned by a 1 deg pitch knock):

- ``apply_correction:=true`` with drivers that do not answer: one whose ``set_camera_info``
  service takes requests and never answers, one with no service (it appears later). The node
  keeps answering every pair, logs and counts each failure in its /diagnostics status, has at
  most one call per side in flight, and tries again every 30 s (not every 10 s, the answer's
  timeout: a driver that never answers is not sent a request each time one times out); the
  driver whose service appeared stores the correction at the next try.
- Rectified input (``image_rect``): the camera_info of those images is the raw camera's (its K,
  D and R are not those of the images; only P is), and the corrected camera_info published
  beside them on ``~/corrected/<side>/camera_info`` describes the rectified images as
  ``calibration_check --write-corrected`` does: K = the stale P[:, :3], D = 0, R from the stale
  rectified frame to the corrected one, P with the stale intrinsics and baseline. Rectified
  again with it as image_proc does (``initUndistortRectifyMap``), the knocked pair's median
  vertical disparity drops from 12-13 px to under a pixel; a driver given the
  correction gets its raw calibration with the corrected rectification.
"""

from __future__ import annotations

import re
import threading
import time

import cv2
import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from ros_helpers import Ros, header, start_node  # noqa: E402
from sensor_msgs.msg import CameraInfo, Image  # noqa: E402
from sensor_msgs.srv import SetCameraInfo  # noqa: E402
from test_node_corrected import (  # noqa: E402
    SIDES,
    Driver,
    KnockedRig,
    Listener,
    decode,
    in_force,
    inputs,
    node_args,
    rectify,
    send_corrected,
    send_until,
    vertical_disparity,
)

from sepfm_ros.ros.msgs.headers import stamp_ns  # noqa: E402
from sepfm_ros.ros.node.corrected import APPLY_RETRY_S, APPLY_TIMEOUT_S  # noqa: E402

pytestmark = pytest.mark.slow  # a minute of pairs for the 30 s retry; 15-45 pairs for rect


class SilentDriver:
    """A driver's ``set_camera_info`` that takes each request and never answers: a node of its
    own (own context, four executor threads, callbacks reentrant) whose callback waits until
    :meth:`close`; the requests' arrival times (a request in a thread of its own each, so
    requests that pile up are seen)."""

    def __init__(self, service: str) -> None:
        from rclpy.callback_groups import ReentrantCallbackGroup

        self.arrivals: list[float] = []
        self.lock = threading.Lock()
        self._release = threading.Event()
        self.ros = Ros("silent_driver", threads=4)
        self.srv = self.ros.node.create_service(
            SetCameraInfo, service, self._on_call, callback_group=ReentrantCallbackGroup()
        )

    def _on_call(self, request, response):
        with self.lock:
            self.arrivals.append(time.monotonic())
        self._release.wait(300.0)  # no answer
        return response

    def count(self) -> int:
        with self.lock:
            return len(self.arrivals)

    def close(self) -> None:
        self._release.set()
        time.sleep(0.5)  # the held calls answer (to nobody) before the node goes
        self.ros.close()


def test_drivers_that_do_not_answer_are_retried_every_30_s(ros, tmp_path, shared_data):
    node, ns = "sepfm_heal_silent", "/heal_silent"
    silent = SilentDriver(f"{ns}/left/set_camera_info")
    t0 = 1_700_600_000 * 10**9
    args = node_args(ns, "apply_correction:=true")
    proc, client = start_node(node, tmp_path, ros, inputs(ns), *args)
    rig = KnockedRig(client, shared_data, ns, t0)
    time.sleep(0.5)
    try:
        n = send_until(rig, client, lambda s: silent.count() > 0)
        first = silent.arrivals[0]
        # the right driver has no service yet: that try failed; it appears now
        late = Driver(ros, f"{ns}/right/set_camera_info")
        k = n
        deadline = first + APPLY_RETRY_S + 60.0
        # every pair is answered (wait_info) while the calls hang; past the first retry
        while time.monotonic() < first + APPLY_RETRY_S + 5.0 or not late.received:
            assert time.monotonic() < deadline, (silent.count(), len(late.received))
            client.wait_info(rig.send(k))
            k += 1
            time.sleep(0.3)
        # the right driver's service appeared: stored at the retry, not called again
        assert len(late.received) == 1
        # the silent driver: its first request, then one retry 30 s after it (not a request
        # every 10 s as each call times out)
        with silent.lock:
            arrivals = list(silent.arrivals)
        print(
            f"{k - n} pairs while waiting; requests to the silent driver at "
            f"{[round(a - first, 1) for a in arrivals]} s"
        )
        assert len(arrivals) >= 2, arrivals  # tried again
        gaps = np.diff(arrivals)  # s between requests: no request every 10 s
        assert np.all(gaps >= APPLY_RETRY_S - 1.0), arrivals
        health = client.latest_health(after=1.0)
        left_value = health[f"set_camera_info {ns}/left/set_camera_info"]
        right_value = health[f"set_camera_info {ns}/right/set_camera_info"]
        # each unanswered call failed once its 10 s ran out (the last may still be running)
        left_failed = re.fullmatch(r"0 stored, (\d+) failed; last: .*", left_value)
        assert left_failed and len(arrivals) - 1 <= int(left_failed[1]) <= len(arrivals)
        assert f"no answer within {APPLY_TIMEOUT_S:.0f} s" in left_value
        assert right_value.startswith("1 stored, 1 failed"), right_value
        assert int(health["set_camera_info_failures"]) == int(left_failed[1]) + 1
        assert int(health["correction_in_force"]) == 1 and int(health["corrections"]) == 1
        out = proc.output()
        assert "the service is not available" in out
        assert f"no answer within {APPLY_TIMEOUT_S:.0f} s" in out
    finally:
        proc.stop()
        silent.close()


# made-up raw calibrations of KITTI's rectified cameras: the camera_info of image_rect is the
# raw camera's (image_proc publishes image_rect beside its driver's camera_info); only P
# describes the rectified images
RAW_K = (
    np.array([[702.0, 0.0, 610.0], [0.0, 699.0, 180.0], [0.0, 0.0, 1.0]]),
    np.array([[705.0, 0.0, 625.0], [0.0, 703.0, 190.0], [0.0, 0.0, 1.0]]),
)
RAW_D = ([-0.3, 0.12, 0.001, -0.0004, 0.0], [-0.28, 0.1, -0.0008, 0.0006, 0.0])
RAW_R = tuple(cv2.Rodrigues(np.radians(v))[0] for v in ([0.3, -0.8, 0.2], [-0.2, -0.5, 0.1]))


def raw_camera_info(stale: CameraInfo, k: int) -> CameraInfo:
    """``stale`` (KITTI's rectified calibration) with the raw camera's K, D and R of side k."""
    info = CameraInfo(header=stale.header, width=stale.width, height=stale.height)
    info.distortion_model = "plumb_bob"
    info.k = [float(v) for v in RAW_K[k].ravel()]
    info.d = [float(v) for v in RAW_D[k]]
    info.r = [float(v) for v in RAW_R[k].ravel()]
    info.p = list(stale.p)
    return info


class RectifiedRig(KnockedRig):
    """The knocked KITTI pairs as ``image_rect`` (KITTI's frames are rectified), each with its
    raw camera's camera_info (:func:`raw_camera_info`)."""

    def camera_info(self, j: int, stamp: int) -> CameraInfo:
        info = raw_camera_info(self.stale[j], j)
        info.header = header(stamp, f"{SIDES[j]}_optical")
        return info


def rect_inputs(ns: str) -> dict[str, tuple[str, type]]:
    return {
        "left": (f"{ns}/left/image_rect", Image),
        "right": (f"{ns}/right/image_rect", Image),
        "left_info": (f"{ns}/left/camera_info", CameraInfo),
        "right_info": (f"{ns}/right/camera_info", CameraInfo),
    }


def test_rectified_input_gets_the_corrected_rectification_of_its_images(ros, tmp_path, shared_data):
    node, ns = "sepfm_heal_rect", "/heal_rect"
    drivers = [Driver(ros, f"{ns}/{side}/set_camera_info") for side in SIDES]
    args = [
        "-r",
        f"left/image_raw:={ns}/left/image_rect",
        "-r",
        f"right/image_raw:={ns}/right/image_rect",
    ]
    for p in (
        "calibration_window:=6",
        "calibration_min_pairs:=3",
        "publish_corrected:=true",
        "apply_correction:=true",
    ):
        args += ["-p", p]
    proc, client = start_node(node, tmp_path, ros, rect_inputs(ns), *args)
    rig = RectifiedRig(client, shared_data, ns, 1_700_700_000 * 10**9)
    listener = Listener(ros, node)
    time.sleep(0.5)
    try:
        n = send_until(rig, client, in_force(listener))
        assert ", rectified images" in proc.output()  # image_rect: taken as rectified
        after = send_corrected(rig, client, listener, n, 3)
        assert sorted(listener.corrected_stamps()) == after
        stamp = after[-1]
        with listener.lock:
            images = [listener.images[s][stamp] for s in SIDES]
            infos = [listener.infos[s][stamp] for s in SIDES]
        for k, (image, info) in enumerate(zip(images, infos, strict=True)):
            assert stamp_ns(info.header.stamp) == stamp
            assert np.array_equal(decode(image), rig.sent[stamp][k])
            stale_P = np.reshape(rig.stale[k].p, (3, 4))
            # the rectified images described as raw ones: K = the stale P's, no distortion
            np.testing.assert_allclose(np.reshape(info.k, (3, 3)), stale_P[:, :3])
            assert not np.any(info.d)
            # P keeps the stale rectified intrinsics and baseline
            np.testing.assert_allclose(np.reshape(info.p, (3, 4))[:, :3], stale_P[:, :3])
        np.testing.assert_allclose(infos[1].p[3], rig.stale[1].p[3], rtol=1e-6)
        left, right = rig.sent[stamp]
        stale = vertical_disparity(left, right)  # rectified with the stale calibration
        corrected = vertical_disparity(rectify(left, infos[0]), rectify(right, infos[1]))
        print(
            f"rectified input, median vertical disparity px: stale {stale:.2f}, "
            f"corrected {corrected:.2f}"
        )
        assert stale > 8.0
        assert corrected < 1.0
        # the drivers get their raw calibration with the corrected rectification
        deadline = time.monotonic() + 10.0
        while not all(d.received for d in drivers) and time.monotonic() < deadline:
            time.sleep(0.05)
        for k, driver in enumerate(drivers):
            assert len(driver.received) == 1
            stored = driver.received[0]
            np.testing.assert_allclose(np.reshape(stored.k, (3, 3)), RAW_K[k])
            np.testing.assert_allclose(stored.d, RAW_D[k])
            # R: the raw frame -> stale rectified -> corrected rectified, P the corrected one,
            # of the correction as it came into force (the corrected topics carry it from the
            # next pair on; it moves by up to 1e-4 over the later pairs, and a wrong
            # composition is off by 1e-2)
            with listener.lock:
                published = list(listener.infos[SIDES[k]].values())
            R_stored = np.reshape(stored.r, (3, 3))
            errors = [
                np.abs(R_stored - np.reshape(i.r, (3, 3)) @ RAW_R[k]).max()
                + np.abs(np.asarray(stored.p) - np.asarray(i.p)).max() / 1e3
                for i in published
            ]
            assert min(errors) < 1e-9, sorted(errors)[:3]
    finally:
        proc.stop()
