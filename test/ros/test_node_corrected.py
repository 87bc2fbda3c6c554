"""The live node's corrected calibration of a knocked stereo rig, over real DDS.

KITTI's stereo frames are sent with the rig's camera_info (the stale calibration) while the
right image is warped by K R K^-1, R a 1 degree pitch of the right camera (the knock), from the
first frame on. Once the calibration check is at WARN and the correction has its pairs:

- ``publish_corrected:=true``: every pair comes back on ``~/corrected/<side>/image_raw`` with
  ``~/corrected/<side>/camera_info`` under the image's own header; rectified the way image_proc
  does (``initUndistortRectifyMap`` with K, D, R and P, then ``remap``), the corrected pair's
  median vertical disparity drops from the stale calibration's 12-13 px to that of the true
  calibration (KITTI's own residual, about 0.3 px); a deactivated node republishes nothing;
- ``apply_correction:=true``: each driver's ``set_camera_info`` service (a server in this test
  process) receives the corrected camera_info once; a driver that refuses is counted;
- the defaults: nothing on the corrected topics, no set_camera_info call;
- ``image_transport:=compressed``: the images come back as received on
  ``~/corrected/<side>/image_raw/compressed``;
- a subscriber of a corrected topic alone makes a node with ``always_on:=false`` hold its inputs.

The vertical disparity is measured on Lucas-Kanade tracks from the left rectified image to the
right one, kept when the track back lands within 0.2 px of its start.
"""

from __future__ import annotations

import json
import threading
import time

import cv2
import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from lifecycle_msgs.msg import State, Transition  # noqa: E402
from lifecycle_msgs.srv import ChangeState, GetState  # noqa: E402
from ros_helpers import (  # noqa: E402
    RELIABLE,
    STARTUP_TIMEOUT,
    NodeProcess,
    call_service,
    header,
    image_msg,
    start_node,
)
from sensor_msgs.msg import CameraInfo, CompressedImage, Image  # noqa: E402
from sensor_msgs.srv import SetCameraInfo  # noqa: E402

from sepfm_ros.ros.bags.synthesis import camera_info_message, camera_infos  # noqa: E402
from sepfm_ros.ros.msgs.diagnostics import status_values  # noqa: E402
from sepfm_ros.ros.msgs.headers import stamp_ns  # noqa: E402
from sepfm_ros.ros.msgs.image_conversion import numpy_to_compressed  # noqa: E402

pytestmark = pytest.mark.slow  # four nodes fed 12-16 KITTI pairs each, and one more: 1.5-4.5 min

SIZE = (1241, 376)
N_FRAMES = 51  # kitti_seq2's stereo frames
KNOCK_DEG = 1.0  # pitch of the right camera
MAX_PAIRS = 45  # pairs sent before a correction must be in force
SIDES = ("left", "right")
KNOCK = cv2.Rodrigues(np.array([np.radians(KNOCK_DEG), 0.0, 0.0]))[0]


class KnockedRig:
    """KITTI stereo pairs with the right image turned by KNOCK, published with the stale
    camera_info under ``ns``; the images sent, by stamp."""

    def __init__(self, client, shared_data, ns: str, t0: int, compressed: bool = False) -> None:
        cams = json.loads((shared_data / "cameras.json").read_text())
        self.paths = [
            (
                shared_data / f"kitti_seq2/left/{k:06d}.png",
                shared_data / f"kitti_seq2/right/{k:06d}.png",
            )
            for k in range(N_FRAMES)
        ]
        first = "kitti_seq2/left/000000.png"
        P = (np.asarray(cams[first]), np.asarray(cams[first.replace("/left/", "/right/")]))
        self.calibs = camera_infos(P, SIZE)
        K_r = self.calibs[1].K
        self.warp = K_r @ KNOCK @ np.linalg.inv(K_r)
        self.client, self.ns, self.t0, self.compressed = client, ns, t0, compressed
        self.messages: dict[int, list] = {}  # the image messages sent, by stamp
        self.sent: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self.stale = [
            camera_info_message(c, SIZE, header(0, f"{s}_optical"))
            for c, s in zip(self.calibs, SIDES, strict=True)
        ]

    def send(self, k: int) -> int:
        """Publish pair ``k`` (camera_info first, as drivers do); its stamp."""
        left_path, right_path = self.paths[k % N_FRAMES]
        left = cv2.imread(str(left_path), cv2.IMREAD_GRAYSCALE)
        right = cv2.warpPerspective(
            cv2.imread(str(right_path), cv2.IMREAD_GRAYSCALE), self.warp, SIZE
        )
        stamp = self.t0 + k * 100_000_000
        for j, side in enumerate(SIDES):
            self.client.publish(f"{side}_info", self.camera_info(j, stamp))
        time.sleep(0.02)
        self.messages[stamp] = []
        for side, img in zip(SIDES, (left, right), strict=True):
            if self.compressed:
                msg = numpy_to_compressed(img, "png", header(stamp, f"{side}_optical"))
            else:
                msg = image_msg(img, stamp)
                msg.header.frame_id = f"{side}_optical"
            self.client.publish(side, msg)
            self.messages[stamp].append(msg)
        self.sent[stamp] = (left, right)
        return stamp

    def camera_info(self, j: int, stamp: int) -> CameraInfo:
        """The camera_info camera ``j`` (0 left, 1 right) is published with: the stale one."""
        side = SIDES[j]
        return camera_info_message(self.calibs[j], SIZE, header(stamp, f"{side}_optical"))


def inputs(ns: str, compressed: bool = False) -> dict[str, tuple[str, type]]:
    """The test client's publishers: the images (raw, or image_transport's compressed) and
    camera_info of both cameras under ``ns``."""
    suffix, image_type = ("/compressed", CompressedImage) if compressed else ("", Image)
    return {
        "left": (f"{ns}/left/image_raw{suffix}", image_type),
        "right": (f"{ns}/right/image_raw{suffix}", image_type),
        "left_info": (f"{ns}/left/camera_info", CameraInfo),
        "right_info": (f"{ns}/right/camera_info", CameraInfo),
    }


def node_args(ns: str, *params: str) -> list[str]:
    args = [
        "-r",
        f"left/image_raw:={ns}/left/image_raw",
        "-r",
        f"right/image_raw:={ns}/right/image_raw",
    ]
    for p in ("calibration_window:=6", "calibration_min_pairs:=3", *params):
        args += ["-p", p]
    return args


class Listener:
    """The node's ~/corrected/<side>/{image_raw,camera_info} by stamp and its
    ~/calibration_check statuses' values by stamp."""

    def __init__(self, ros, node: str, compressed: bool = False) -> None:
        self.lock = threading.Lock()
        self.images: dict[str, dict[int, Image]] = {s: {} for s in SIDES}
        self.infos: dict[str, dict[int, CameraInfo]] = {s: {} for s in SIDES}
        self.checks: dict[int, dict[str, str]] = {}
        for side in SIDES:
            image = (
                ("image_raw/compressed", CompressedImage) if compressed else ("image_raw", Image)
            )
            for (kind, msg_type), store in (
                (image, self.images),
                (("camera_info", CameraInfo), self.infos),
            ):
                ros.node.create_subscription(
                    msg_type, f"/{node}/corrected/{side}/{kind}", self._keep(store[side]), RELIABLE
                )
        ros.node.create_subscription(
            DiagnosticArray, f"/{node}/calibration_check", self._on_check, RELIABLE
        )

    def _keep(self, store):
        def keep(msg):
            with self.lock:
                store[stamp_ns(msg.header.stamp)] = msg

        return keep

    def _on_check(self, msg):
        with self.lock:
            for status in msg.status:
                self.checks[stamp_ns(msg.header.stamp)] = status_values(status)

    def check(self, stamp: int, timeout: float = 10.0) -> dict[str, str]:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            with self.lock:
                if stamp in self.checks:
                    return self.checks[stamp]
            time.sleep(0.01)
        raise AssertionError(f"no ~/calibration_check stamped {stamp}")

    def corrected_stamps(self) -> set[int]:
        """Stamps with both images and both camera_infos received."""
        with self.lock:
            sets = [set(self.images[s]) & set(self.infos[s]) for s in SIDES]
        return sets[0] & sets[1]

    def count(self) -> int:
        with self.lock:
            return sum(len(self.images[s]) + len(self.infos[s]) for s in SIDES)


class Driver:
    """A camera driver's ``set_camera_info`` service in the test process: keeps each request's
    camera_info and answers ``success`` (False: with a status message)."""

    def __init__(self, ros, service: str, success: bool = True) -> None:
        self.received: list[CameraInfo] = []
        self.success = success
        self.srv = ros.node.create_service(SetCameraInfo, service, self._on_call)

    def _on_call(self, request, response):
        self.received.append(request.camera_info)
        response.success = self.success
        response.status_message = "" if self.success else "cannot write the calibration file"
        return response


def decode(msg: Image) -> np.ndarray:
    assert msg.encoding == "mono8"
    return np.frombuffer(bytes(msg.data), np.uint8).reshape(msg.height, msg.step)[:, : msg.width]


def rectify(img: np.ndarray, info) -> np.ndarray:
    """``img`` rectified as image_proc does with a CameraInfo (or a synthesis Calibration)."""
    if isinstance(info, CameraInfo):
        K, D = np.reshape(info.k, (3, 3)), np.asarray(info.d)
        R, P = np.reshape(info.r, (3, 3)), np.reshape(info.p, (3, 4))
    else:
        K, D, R, P = info.K, np.zeros(5), info.R, info.P
    size = (img.shape[1], img.shape[0])
    map1, map2 = cv2.initUndistortRectifyMap(K, D, R, P[:, :3], size, cv2.CV_32FC1)
    return cv2.remap(img, map1, map2, cv2.INTER_LINEAR)


def vertical_disparity(left: np.ndarray, right: np.ndarray) -> float:
    """Median |v_right - v_left| (px) of forward-backward consistent LK tracks left -> right."""
    p = cv2.goodFeaturesToTrack(left, 3000, 0.01, 7)
    q, st, _ = cv2.calcOpticalFlowPyrLK(left, right, p, None, winSize=(21, 21), maxLevel=5)
    back, st2, _ = cv2.calcOpticalFlowPyrLK(right, left, q, None, winSize=(21, 21), maxLevel=5)
    ok = (st.ravel() == 1) & (st2.ravel() == 1)
    ok &= np.linalg.norm((back - p).reshape(-1, 2), axis=1) < 0.2
    d = (q - p).reshape(-1, 2)[ok]
    d = d[(d[:, 0] < 2.0) & (np.abs(d[:, 1]) < 40.0)]  # right of the left point, same band
    assert len(d) > 100, f"only {len(d)} tracks"
    return float(np.median(np.abs(d[:, 1])))


def true_right(calib):
    """The right camera's true calibration after the knock: the stale one with R undoing it."""
    return type(calib)(calib.K, KNOCK.T @ calib.R, calib.P)


def send_until(rig: KnockedRig, client, done, first: int = 0) -> int:
    """Send pairs (each answered before the next) until ``done(stamp)``; the pairs sent."""
    for k in range(first, first + MAX_PAIRS):
        stamp = rig.send(k)
        client.wait_info(stamp)
        if done(stamp):
            return k + 1 - first
    raise AssertionError(f"not done after {MAX_PAIRS} knocked pairs")


def send_corrected(rig: KnockedRig, client, listener: Listener, first: int, count: int) -> list:
    """Send ``count`` pairs from ``first`` (each answered before the next) and wait up to 10 s
    for them on the corrected topics; their stamps."""
    sent = []
    for k in range(first, first + count):
        sent.append(rig.send(k))
        client.wait_info(sent[-1])
    deadline = time.monotonic() + 10.0
    while not set(sent) <= listener.corrected_stamps() and time.monotonic() < deadline:
        time.sleep(0.05)
    return sent


def in_force(listener: Listener):
    def done(stamp: int) -> bool:
        return not listener.check(stamp).get("correction", "none").startswith("none")

    return done


def test_corrected_topics_rectify_the_knocked_rig(ros, tmp_path, shared_data):
    node, ns = "sepfm_heal", "/heal"
    drivers = [Driver(ros, f"{ns}/{side}/set_camera_info") for side in SIDES]
    args = node_args(ns, "publish_corrected:=true")
    proc, client = start_node(node, tmp_path, ros, inputs(ns), *args)
    rig = KnockedRig(client, shared_data, ns, 1_700_200_000 * 10**9)
    listener = Listener(ros, node)
    time.sleep(0.5)
    try:
        n = send_until(rig, client, in_force(listener))
        checks = [listener.check(s) for s in sorted(rig.sent)]
        assert checks[0]["correction"].startswith("none"), checks[0]
        values = checks[-1]
        print(f"correction in force after {n} pairs: {values['correction']}")
        assert abs(float(values["correction_pitch_deg"])) == pytest.approx(KNOCK_DEG, abs=0.1)
        after = send_corrected(rig, client, listener, n, 4)
        got = listener.corrected_stamps()
        # every pair formed while the correction is in force comes back; none before it
        assert sorted(got) == after, (after, sorted(got))
        with listener.lock:
            for stamp in after:
                for k, side in enumerate(SIDES):
                    image, info = listener.images[side][stamp], listener.infos[side][stamp]
                    # the image's own header on both, the image unchanged
                    assert image.header.frame_id == info.header.frame_id == f"{side}_optical"
                    assert stamp_ns(image.header.stamp) == stamp_ns(info.header.stamp) == stamp
                    assert np.array_equal(decode(image), rig.sent[stamp][k])
                    # K and D as received, R and P of the new rectification
                    assert np.allclose(info.k, rig.stale[k].k) and np.allclose(
                        info.d, rig.stale[k].d
                    )
                    assert (info.width, info.height) == SIZE
            left_msg, right_msg = (listener.images[s][after[-1]] for s in SIDES)
            left_info, right_info = (listener.infos[s][after[-1]] for s in SIDES)
        left, right = decode(left_msg), decode(right_msg)
        stale = vertical_disparity(rectify(left, rig.calibs[0]), rectify(right, rig.calibs[1]))
        true = vertical_disparity(
            rectify(left, rig.calibs[0]), rectify(right, true_right(rig.calibs[1]))
        )
        corrected = vertical_disparity(rectify(left, left_info), rectify(right, right_info))
        print(
            f"median vertical disparity px: stale {stale:.2f}, "
            f"corrected {corrected:.2f}, true {true:.2f}"
        )
        assert stale > 8.0
        assert corrected < 1.0 and corrected < true + 0.3
        health = client.latest_health(after=0.0)
        assert int(health["correction_in_force"]) == 1 and int(health["corrections"]) == 1
        assert int(health["corrected_pairs_published"]) >= len(after)
        assert all(d.received == [] for d in drivers), "apply_correction is off by default"
        # deactivated: no input, nothing republished
        change = ros.node.create_client(ChangeState, f"/{node}/change_state")
        get = ros.node.create_client(GetState, f"/{node}/get_state")
        deactivate = Transition(id=Transition.TRANSITION_DEACTIVATE)

        def deactivated() -> ChangeState.Response | None:
            state = call_service(get, GetState.Request(), timeout=30.0).current_state.id
            inactive = state == State.PRIMARY_STATE_INACTIVE
            return ChangeState.Response(success=True) if inactive else None

        request = ChangeState.Request(transition=deactivate)
        assert call_service(change, request, timeout=30.0, answered=deactivated).success
        deadline = time.monotonic() + 30.0
        while ros.node.count_subscribers(f"{ns}/left/image_raw") and time.monotonic() < deadline:
            time.sleep(0.05)
        before = listener.count()
        for k in range(n + 4, n + 7):
            rig.send(k)
        time.sleep(3.0)
        assert listener.count() == before
    finally:
        proc.stop()


def test_apply_correction_sends_it_to_each_driver_once(ros, tmp_path, shared_data):
    node, ns = "sepfm_heal_apply", "/heal_apply"
    left_driver = Driver(ros, f"{ns}/left/set_camera_info")
    right_driver = Driver(ros, f"{ns}/right/set_camera_info", success=False)
    t0 = 1_700_300_000 * 10**9
    args = node_args(ns, "apply_correction:=true")
    proc, client = start_node(node, tmp_path, ros, inputs(ns), *args)
    rig = KnockedRig(client, shared_data, ns, t0)
    listener = Listener(ros, node)
    time.sleep(0.5)
    try:
        n = send_until(rig, client, lambda s: bool(left_driver.received and right_driver.received))
        for k in range(n, n + 4):  # the same correction stays in force: not sent again
            client.wait_info(rig.send(k))
        time.sleep(1.0)
        assert len(left_driver.received) == 1 and len(right_driver.received) == 1
        infos = [left_driver.received[0], right_driver.received[0]]
        for k, info in enumerate(infos):
            assert info.header.frame_id == f"{SIDES[k]}_optical"
            assert np.allclose(info.k, rig.stale[k].k) and np.allclose(info.d, rig.stale[k].d)
        left, right = rig.sent[max(rig.sent)]
        stale = vertical_disparity(rectify(left, rig.calibs[0]), rectify(right, rig.calibs[1]))
        corrected = vertical_disparity(rectify(left, infos[0]), rectify(right, infos[1]))
        print(f"median vertical disparity px: stale {stale:.2f}, stored {corrected:.2f}")
        assert stale > 8.0 and corrected < 1.0
        health = client.latest_health(after=1.5)
        assert int(health["set_camera_info_failures"]) == 1  # the right driver refused
        assert health[f"set_camera_info {ns}/left/set_camera_info"].startswith("1 stored, 0 failed")
        assert (
            "cannot write the calibration file"
            in health[f"set_camera_info {ns}/right/set_camera_info"]
        )
        assert "apply_correction on" in proc.output()
        # publish_corrected is off by default: no corrected topics
        assert ros.node.count_publishers(f"/{node}/corrected/left/image_raw") == 0
        assert listener.count() == 0
    finally:
        proc.stop()


def test_defaults_publish_no_corrected_topics_and_call_no_driver(ros, tmp_path, shared_data):
    node, ns = "sepfm_heal_defaults", "/heal_defaults"
    drivers = [Driver(ros, f"{ns}/{side}/set_camera_info") for side in SIDES]
    t0 = 1_700_400_000 * 10**9
    proc, client = start_node(node, tmp_path, ros, inputs(ns), *node_args(ns))
    rig = KnockedRig(client, shared_data, ns, t0)
    listener = Listener(ros, node)
    time.sleep(0.5)
    try:
        n = send_until(rig, client, in_force(listener))
        for k in range(n, n + 3):
            client.wait_info(rig.send(k))
        time.sleep(1.0)
        health = client.latest_health(after=0.0)
        assert int(health["correction_in_force"]) == 1
        for side in SIDES:
            for kind in ("image_raw", "camera_info"):
                assert ros.node.count_publishers(f"/{node}/corrected/{side}/{kind}") == 0
        assert listener.count() == 0
        assert all(d.received == [] for d in drivers)
        assert "set_camera_info_failures" not in health
    finally:
        proc.stop()


def test_compressed_input_comes_back_on_the_compressed_corrected_topic(ros, tmp_path, shared_data):
    node, ns = "sepfm_heal_compressed", "/heal_compressed"
    t0 = 1_700_500_000 * 10**9
    args = node_args(ns, "publish_corrected:=true", "image_transport:=compressed")
    proc, client = start_node(node, tmp_path, ros, inputs(ns, compressed=True), *args)
    rig = KnockedRig(client, shared_data, ns, t0, compressed=True)
    listener = Listener(ros, node, compressed=True)
    time.sleep(0.5)
    try:
        n = send_until(rig, client, in_force(listener))
        after = send_corrected(rig, client, listener, n, 2)
        assert sorted(listener.corrected_stamps()) == after
        assert ros.node.count_publishers(f"/{node}/corrected/left/image_raw") == 0
        with listener.lock:
            for stamp in after:
                for k, side in enumerate(SIDES):
                    image, info = listener.images[side][stamp], listener.infos[side][stamp]
                    sent = rig.messages[stamp][k]
                    assert image.format == sent.format and bytes(image.data) == bytes(sent.data)
                    assert stamp_ns(info.header.stamp) == stamp
                    assert info.header.frame_id == image.header.frame_id == f"{side}_optical"
    finally:
        proc.stop()


def test_a_subscriber_of_the_corrected_topics_is_demand(ros, tmp_path):
    node, ns = "sepfm_heal_demand", "/heal_demand"
    # reliable: the inputs are subscribed at once (auto waits for their publishers)
    args = node_args(
        ns, "publish_corrected:=true", "always_on:=false", "input_reliability:=reliable"
    )
    proc = NodeProcess(node, tmp_path, *args)
    topic = f"{ns}/left/image_raw"

    def wait(condition, what: str) -> None:
        deadline = time.monotonic() + STARTUP_TIMEOUT
        while not condition():
            assert time.monotonic() < deadline, f"{what}:\n{proc.output()}"
            time.sleep(0.1)

    try:
        wait(
            lambda: ros.node.count_publishers(f"/{node}/corrected/left/image_raw") == 1, "no topic"
        )
        time.sleep(2.0)  # active, idle: no subscriber of any output
        assert ros.node.count_subscribers(topic) == 0
        sub = ros.node.create_subscription(
            CameraInfo, f"/{node}/corrected/right/camera_info", lambda m: None, RELIABLE
        )
        wait(lambda: ros.node.count_subscribers(topic) == 1, "the subscriber is not demand")
        ros.node.destroy_subscription(sub)
        wait(lambda: ros.node.count_subscribers(topic) == 0, "inputs held without demand")
    finally:
        proc.stop()
