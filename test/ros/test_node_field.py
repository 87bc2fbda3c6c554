"""The live node as a user's robot meets it, at default settings (no QoS overrides): a camera
publishing with ROS 2's default QoS, remapped compressed topics, stamps that jump back, a stereo
rig whose right camera lags, and a flood of malformed images among real frames.

Each test starts its own node subprocess (its subscriptions adapt to the first publishers).
"""

from __future__ import annotations

import json
import time

import cv2
import numpy as np
import pytest
from ground_truth import gt_fundamental, median_gt_inlier_error

rclpy = pytest.importorskip("rclpy")

from diagnostic_msgs.msg import DiagnosticStatus  # noqa: E402
from rclpy.qos import QoSProfile, qos_profile_sensor_data  # noqa: E402
from ros_helpers import image_msg, send_pair, start_node  # noqa: E402
from sensor_msgs.msg import CompressedImage, Image  # noqa: E402

from sepfm_ros.ros.msgs.headers import stamp_ns  # noqa: E402
from sepfm_ros.ros.msgs.image_conversion import numpy_to_compressed  # noqa: E402
from sepfm_ros.ros.node import dds  # noqa: E402

# ROS 2's default publisher QoS (reliable, keep-last 10), as a camera driver's publisher has it
DEFAULT_QOS = QoSProfile(depth=10)
TEMPLE = [f"templeRing/templeR{k:04d}.png" for k in range(1, 21)]
KITTI = [(f"kitti_seq2/left/{k:06d}.png", f"kitti_seq2/right/{k:06d}.png") for k in range(0, 10)]
T0 = 1_700_000_000 * 10**9  # stamps of these tests (ns)


@pytest.fixture(scope="module")
def images(shared_data):
    cache: dict[tuple[str, int], np.ndarray] = {}

    def load(rel: str, flags: int = cv2.IMREAD_GRAYSCALE) -> np.ndarray:
        if (rel, flags) not in cache:
            cache[(rel, flags)] = cv2.imread(str(shared_data / rel), flags)
            assert cache[(rel, flags)] is not None, rel
        return cache[(rel, flags)]

    return load


def bgr_msg(bgr: np.ndarray, stamp: int) -> Image:
    """A bgr8 sensor_msgs/Image of the colour image ``bgr`` (H, W, 3)."""
    msg = image_msg(bgr[..., 0], stamp)
    msg.encoding = "bgr8"
    msg.step = 3 * bgr.shape[1]
    msg.data = np.ascontiguousarray(bgr).tobytes()
    return msg


def gt_error(shared_data, values, F, cloud, img_a, img_b) -> float:
    pts_a = np.stack([cloud["u_a"], cloud["v_a"]], axis=1).astype(np.float64)
    pts_b = np.stack([cloud["u_b"], cloud["v_b"]], axis=1).astype(np.float64)
    err, n_gt = median_gt_inlier_error(F, gt_fundamental(shared_data, img_a, img_b), pts_a, pts_b)
    assert n_gt >= 20, f"{img_a} -> {img_b}: only {n_gt} GT-inlier matches"
    return err


def wait_health(
    client, predicate, timeout: float = 15.0, since: int | None = None
) -> dict[str, str]:
    """The first /diagnostics report of the client's node (from now on, or from report number
    ``since``) that satisfies ``predicate(values, level, message)``; fails with the last report
    after ``timeout``."""
    with client.lock:
        start = len(client.health) if since is None else since
    deadline = time.monotonic() + timeout
    last = None
    while time.monotonic() < deadline:
        with client.lock:
            reports = list(zip(client.health[start:], client.health_log[start:], strict=True))
        for values, (_, level, message) in reports:
            last = (values, level, message)
            if predicate(values, level, message):
                return values | {"_level": level, "_message": message}
        time.sleep(0.05)
    raise AssertionError(f"no matching /diagnostics report within {timeout} s; last: {last}")


MAX_FRAMES = 40  # the most frames a loss test publishes before it gives up


def _any_report(client, since: int, predicate) -> bool:
    """Whether a /diagnostics report from number ``since`` on satisfies ``predicate``."""
    with client.lock:
        reports = list(zip(client.health[since:], client.health_log[since:], strict=True))
    return any(predicate(values, level, message) for values, (_, level, message) in reports)


def paced(period_s: float):
    """Yields k = 0, 1, ... at ``period_s`` intervals (a camera's pace)."""
    start = time.monotonic()
    k = 0
    while True:
        delay = start + k * period_s - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        yield k
        k += 1


def test_default_qos_colour_camera_every_pair_answered_then_stamps_jump_back(
    ros, tmp_path, images, shared_data
):
    """640x480 bgr8 at 4 Hz with ROS 2's default QoS, node at default settings."""
    proc, client = start_node(
        "field_motion",
        tmp_path,
        ros,
        {"image": ("/robot/camera/image_raw", Image)},
        "-p",
        "mode:=motion",
        "-r",
        "image_raw:=/robot/camera/image_raw",
        "-p",
        "diagnostic_updater.period:=0.5",
        input_qos=DEFAULT_QOS,
    )
    try:
        health = client.latest_health(after=0.0)
        assert health["input_reliability_image"] == "reliable"
        stamps = []
        for k in paced(0.25):
            if k == len(TEMPLE):
                break
            stamp = T0 + k * 250_000_000
            stamps.append(stamp)
            client.publish("image", bgr_msg(images(TEMPLE[k], cv2.IMREAD_COLOR), stamp))
        client.wait_info(stamps[-1])  # reliable: the newest pair is always answered
        answered, formed, dropped = client.wait_settled(health, stamps[1:])
        # every frame arrived (reliable QoS) and every pair was answered, or dropped and counted
        # when the node fell behind the camera (a loaded machine)
        assert formed == len(TEMPLE) - 1 and len(answered) + dropped == formed, (answered, dropped)
        # views listed as a pair in pairs.json (a few consecutive views of the ring are not)
        listed = {
            (e["img_a"], e["img_b"]) for e in json.loads((shared_data / "pairs.json").read_text())
        }
        errors = []
        for stamp in answered:
            k = stamps.index(stamp)
            values, F, cloud = client.wait_outputs(stamp)
            # the pair is the one its stamps say: frame k-1 with frame k
            assert stamp_ns(values.stamp_a) == stamps[k - 1]
            if (TEMPLE[k - 1], TEMPLE[k]) in listed:
                errors.append(gt_error(shared_data, values, F, cloud, TEMPLE[k - 1], TEMPLE[k]))
        assert max(errors) < 1.0, errors
        # the stamps jump back (a looped bag): answers go on from the second frame after it
        # (each frame sent once the pair before is answered, so none is dropped however busy)
        back = [T0 - 100 * 10**9 + k * 250_000_000 for k in range(4)]
        for k, stamp in enumerate(back):
            client.publish("image", bgr_msg(images(TEMPLE[k], cv2.IMREAD_COLOR), stamp))
            if k > 0:
                values, F, _ = client.wait_outputs(stamp)
                assert F is not None, values.status_text
        report = wait_health(client, lambda v, lv, m: int(v["stamp_jumps"]) == 1)
        assert report["_level"] == int.from_bytes(DiagnosticStatus.WARN, "little")
        assert "jumped back" in report["_message"]
        assert "stamps jumped back" in proc.output()
    finally:
        proc.stop()


def test_sensor_data_qos_camera_is_received_best_effort(ros, tmp_path, images, shared_data):
    proc, client = start_node(
        "field_best_effort",
        tmp_path,
        ros,
        {"image": ("/be/image_raw", Image)},
        "-p",
        "mode:=motion",
        "-r",
        "image_raw:=/be/image_raw",
        input_qos=qos_profile_sensor_data,
    )
    try:
        health = client.latest_health(after=0.0)
        assert health["input_reliability_image"] == "best_effort"
        stamps = []
        for k in paced(0.25):
            if k == 6:
                break
            stamps.append(T0 + k * 250_000_000)
            client.publish("image", image_msg(images(TEMPLE[12 + k]), stamps[-1]))
        answered, formed, dropped = client.wait_settled(health, stamps[1:])
        # pairs reaching the node over loopback best effort: each answered or dropped-and-counted
        # (the node fell behind the camera on a loaded machine)
        assert formed >= 3, f"{formed} of 5 mono8 pairs reached the node over loopback"
        assert answered and len(answered) + dropped == formed, (answered, dropped)
        for stamp in answered:
            k = stamps.index(stamp)
            values, F, cloud = client.wait_outputs(stamp)
            img_a, img_b = TEMPLE[11 + k], TEMPLE[12 + k]  # views 13-18: consecutive pairs
            assert gt_error(shared_data, values, F, cloud, img_a, img_b) < 1.0
    finally:
        proc.stop()


# the node as a user starts it: no discovery range set (this suite keeps its own processes on
# LOCALHOST, where rmw_fastrtps chooses the transports itself; see sepfm_ros/ros/dds.py)
USER_DISCOVERY = {"ROS_AUTOMATIC_DISCOVERY_RANGE": None, "ROS_LOCALHOST_ONLY": None}


def udp_input_expected() -> bool:
    """Whether the kernel lets the node take its input over UDP (dds.MIN_UDP_SOCKET_BYTES)."""
    return dds.read_rmem_max() >= dds.MIN_UDP_SOCKET_BYTES


def input_over_udp(health: dict[str, str]) -> bool:
    """Whether the node takes its input over UDP, checked against what the kernel allows."""
    udp = udp_input_expected()
    transport = health["dds_input_transport"]
    assert transport.startswith("UDP" if udp else "shared memory"), transport
    return udp


def assert_loss_reported_with_sysctl(client, proc, key: str) -> None:
    """The shared-memory branch: lost samples counted (``key`` in /diagnostics) and the log
    naming the sysctl that lets the node take its input over UDP."""
    wait_health(client, lambda v, lv, m: int(v.get(key, 0)) > 0, timeout=20.0)
    assert dds.RMEM_SYSCTL in proc.output()


def all_with_f(client, answered: list[int]) -> bool:
    """Whether the node answered each of the output stamps ``answered`` (at least one) with
    an F."""
    return bool(answered) and all(client.wait_outputs(s)[1] is not None for s in answered)


def test_best_effort_colour_camera_every_pair_answered(ros, tmp_path, images, shared_data):
    """640x480 bgr8 (900 KiB a frame) at 4 Hz from a sensor-data QoS (best-effort) publisher:
    over Fast DDS's shared memory every frame was lost (0 of 19 pairs answered)."""
    proc, client = start_node(
        "field_be_colour",
        tmp_path,
        ros,
        {"image": ("/be_colour/image_raw", Image)},
        "-p",
        "mode:=motion",
        "-r",
        "image_raw:=/be_colour/image_raw",
        "-p",
        "diagnostic_updater.period:=0.5",
        input_qos=qos_profile_sensor_data,
        env=USER_DISCOVERY,
    )
    try:
        health = client.latest_health(after=0.0)
        assert health["input_reliability_image"] == "best_effort"
        udp = input_over_udp(health)
        stamps = []
        for k in paced(0.25):
            if k == len(TEMPLE):
                break
            stamps.append(T0 + k * 250_000_000)
            client.publish("image", bgr_msg(images(TEMPLE[k], cv2.IMREAD_COLOR), stamps[-1]))
        if not udp:  # the kernel's limit keeps shared memory: the loss is reported with its fix
            assert_loss_reported_with_sysctl(client, proc, "lost_samples_/be_colour/image_raw")
            return
        answered, formed, dropped = client.wait_settled(health, stamps[1:])
        assert formed >= 18, f"{formed} of 19 best-effort bgr8 pairs reached the node"
        assert len(answered) + dropped == formed and all_with_f(client, answered)
        health = client.latest_health(after=0.0)
        assert int(health.get("lost_samples", 0)) <= 1, health
    finally:
        proc.stop()


def test_best_effort_stereo_rig_every_pair_answered(ros, tmp_path, images, shared_data):
    """Two best-effort 1241x376 mono8 cameras (456 KiB a frame, published together): over
    shared memory the left frames were lost."""
    proc, client = start_node(
        "field_be_stereo",
        tmp_path,
        ros,
        {"left": ("/be_rig/left/image_raw", Image), "right": ("/be_rig/right/image_raw", Image)},
        "-p",
        "mode:=stereo",
        "-r",
        "left/image_raw:=/be_rig/left/image_raw",
        "-r",
        "right/image_raw:=/be_rig/right/image_raw",
        input_qos=qos_profile_sensor_data,
        env=USER_DISCOVERY,
    )
    try:
        health = client.latest_health(after=0.0)
        assert health["input_reliability_left"] == "best_effort"
        udp = input_over_udp(health)
        stamps = []
        for k in paced(0.25):
            if k == len(KITTI):
                break
            stamps.append(T0 + k * 250_000_000)
            left, right = KITTI[k]
            send_pair(
                client, image_msg(images(left), stamps[-1]), image_msg(images(right), stamps[-1])
            )
        if not udp:  # the kernel's limit keeps shared memory: the loss is reported with its fix
            assert_loss_reported_with_sysctl(client, proc, "lost_samples")
            return
        answered, formed, dropped = client.wait_settled(health, stamps)
        assert formed >= 9, f"{formed} of 10 best-effort stereo pairs reached the node"
        assert len(answered) + dropped == formed and all_with_f(client, answered)
    finally:
        proc.stop()


def test_localhost_range_best_effort_loss_is_counted_with_its_fix(ros, tmp_path, images):
    """With ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST rmw_fastrtps keeps shared memory, which
    cannot carry a best-effort 900 KiB frame: the node counts the loss and names the fix."""
    proc, client = start_node(
        "field_be_localhost",
        tmp_path,
        ros,
        {"image": ("/be_local/image_raw", Image)},
        "-p",
        "mode:=motion",
        "-r",
        "image_raw:=/be_local/image_raw",
        "-p",
        "diagnostic_updater.period:=0.5",
        input_qos=qos_profile_sensor_data,
        env={"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"},
    )
    try:
        health = client.latest_health(after=0.0)
        assert "localhost" in health["dds_input_transport"]
        # A lost sample is detected by the gap before the next one that arrives (shared memory
        # delivers a large frame now and then, more often on a busy machine): the camera keeps
        # publishing until the node has counted a loss, at most MAX_FRAMES frames.
        with client.lock:
            since = len(client.health)
        lost = lambda v, lv, m: int(v.get("lost_samples_/be_local/image_raw", 0)) > 0  # noqa: E731
        published = 0
        for k in paced(0.25):
            if k == MAX_FRAMES or _any_report(client, since, lost):
                break
            img = images(TEMPLE[k % len(TEMPLE)], cv2.IMREAD_COLOR)
            client.publish("image", bgr_msg(img, T0 + k))
            published += 1
        report = wait_health(client, lost, 20.0, since=since)
        assert report["_level"] == int.from_bytes(DiagnosticStatus.WARN, "little")
        assert int(report["received_image"]) < published  # frames were lost, not all delivered
        assert "ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET" in proc.output()
    finally:
        proc.stop()


def test_compressed_transport_follows_remaps(ros, tmp_path, images, shared_data):
    """image_transport's rule: remap the base topic, then add /compressed."""
    proc, client = start_node(
        "field_compressed",
        tmp_path,
        ros,
        {
            "left": ("/robot/cam/left/image_raw/compressed", CompressedImage),
            "right": ("/robot/cam/right/image_raw/compressed", CompressedImage),
        },
        "-r",
        "left/image_raw:=/robot/cam/left/image_raw",
        "-r",
        "right/image_raw:=/robot/cam/right/image_raw",
        "-p",
        "image_transport:=compressed",
        input_qos=DEFAULT_QOS,
    )
    try:
        img_a, img_b = KITTI[0]
        stamp = T0
        left = numpy_to_compressed(images(img_a), "png")
        right = numpy_to_compressed(images(img_b), "png")
        for msg in (left, right):
            msg.header.stamp.sec, msg.header.stamp.nanosec = stamp // 10**9, stamp % 10**9
        send_pair(client, left, right)
        values, F, cloud = client.wait_outputs(stamp)
        assert gt_error(shared_data, values, F, cloud, img_a, img_b) < 1.0
        assert "/robot/cam/left/image_raw/compressed" in proc.output()
    finally:
        proc.stop()


def test_lagging_right_camera_warns_with_offset_then_pairs_nearest(
    ros, tmp_path, images, shared_data
):
    """Right stamps 12 ms after left at 10 Hz: the default 5 ms slop pairs nothing, which
    /diagnostics says with the measured offset; a slop of half the frame period pairs each left
    frame with its own right frame."""
    proc, client = start_node(
        "field_lag",
        tmp_path,
        ros,
        {"left": ("/lag/left/image_raw", Image), "right": ("/lag/right/image_raw", Image)},
        "-r",
        "left/image_raw:=/lag/left/image_raw",
        "-r",
        "right/image_raw:=/lag/right/image_raw",
        "-p",
        "diagnostic_updater.period:=0.25",
        input_qos=DEFAULT_QOS,
    )
    lag = 12_000_000
    period = 100_000_000
    try:
        frames = {k: (images(a), images(b)) for k, (a, b) in enumerate(KITTI)}
        pace = paced(0.2)  # stamps 100 ms apart, sent at 5 Hz (a loaded 2-core machine)
        with client.lock:
            sending = len(client.health)  # the warning holds only while images arrive
        for k in range(15):
            next(pace)
            left, right = frames[k % len(KITTI)]
            stamp = T0 + k * period
            send_pair(client, image_msg(left, stamp), image_msg(right, stamp + lag))
        report = wait_health(
            client, lambda v, lv, m: "no pair formed" in m, timeout=5.0, since=sending
        )
        assert report["_level"] == int.from_bytes(DiagnosticStatus.WARN, "little")
        assert "+12.0 ms" in report["_message"] and "sync_slop_s" in report["_message"]
        with client.lock:
            assert not client.info
        ok, reason = client.set_parameter("sync_slop_s", 0.05)
        assert ok, reason
        stamps = []
        for k in range(15, 15 + len(KITTI)):
            next(pace)
            left, right = frames[k % len(KITTI)]
            stamp = T0 + k * period
            stamps.append((k, stamp))
            send_pair(client, image_msg(left, stamp), image_msg(right, stamp + lag))
        client.wait_info(stamps[-1][1])  # reliable: the newest pair is always answered
        # pairs formed since the slop changed (the node's first: none before, asserted above; a
        # frame left waiting from before may pair too): each answered or, the node behind on a
        # loaded machine, dropped and counted
        sent = [T0 + k * period for k in range(15 + len(KITTI))]
        node_start = {"synchronized_pairs": "0", "dropped_pairs": "0"}
        answered, formed, dropped = client.wait_settled(node_start, sent)
        assert formed >= len(stamps) and len(answered) + dropped == formed, (answered, dropped)
        for k, stamp in stamps:
            if stamp not in answered:
                continue
            values, F, cloud = client.wait_outputs(stamp)
            # paired with its own right frame (12 ms), not the previous one (88 ms)
            assert stamp_ns(values.stamp_b) == stamp + lag
            img_a, img_b = KITTI[k % len(KITTI)]
            assert gt_error(shared_data, values, F, cloud, img_a, img_b) < 1.0
        wait_health(client, lambda v, lv, m: lv == 0, timeout=15.0)
    finally:
        proc.stop()


def malformed_messages(rng: np.random.Generator, count: int) -> list[Image]:
    """Images wrong in a way the node's callback rejects: a step shorter than a row, data
    shorter or longer than step x height, an unknown encoding, zero size (up to VGA colour)."""
    out = []
    for k in range(count):
        w, h = int(rng.integers(1, 641)), int(rng.integers(1, 481))
        step, n = 3 * w, 3 * w * h
        encoding = "bgr8"
        kind = k % 4
        if kind == 0:
            step = int(rng.integers(0, 3 * w))
        elif kind == 1:
            n = int(rng.integers(0, n)) if rng.random() < 0.5 else n + int(rng.integers(1, 8192))
        elif kind == 2:
            encoding = "not_an_encoding"
        else:
            w, n = 0, int(rng.integers(0, 256))
        msg = image_msg(np.zeros((1, 1), np.uint8), 0)
        msg.width, msg.height, msg.step, msg.encoding = w, h, step, encoding
        msg.data = rng.bytes(n)
        out.append(msg)
    return out


def test_real_frames_answered_under_a_flood_of_malformed_images(ros, tmp_path, images):
    """5,000 malformed images among 41 real frames at 3 Hz, reliable QoS, default settings."""
    rng = np.random.default_rng(11)
    bad = malformed_messages(rng, 64)
    proc, client = start_node(
        "field_flood",
        tmp_path,
        ros,
        {"image": ("/flood/image_raw", Image)},
        "-p",
        "mode:=motion",
        "-r",
        "image_raw:=/flood/image_raw",
        input_qos=DEFAULT_QOS,
    )
    frames, per_frame = 41, 5000 // 40
    try:
        before = client.latest_health(after=0.0)
        stamps, sent_bad = [], 0
        for k in paced(1 / 3):
            if k == frames:
                break
            stamp = T0 + k * 333_000_000
            stamps.append(stamp)
            client.publish("image", image_msg(images(TEMPLE[12 + k % 8]), stamp))
            if k == frames - 1:
                break
            start = time.monotonic()
            for j in range(per_frame):  # spread over most of the frame period
                delay = start + j * 0.3 / per_frame - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
                msg = bad[(k * per_frame + j) % len(bad)]
                msg.header.stamp.sec = (stamp + j + 1) // 10**9
                msg.header.stamp.nanosec = (stamp + j + 1) % 10**9
                client.publish("image", msg)
                sent_bad += 1
        answers, formed, dropped = client.wait_settled(before, stamps[1:])
        answered = len(answers)
        health = client.latest_health(after=0.0)
        print(f"flood: {answered}/{len(stamps) - 1} real pairs answered, {sent_bad} malformed")
        print({k: v for k, v in health.items() if k.startswith(("errors", "lost", "dropped"))})
        assert sent_bad >= 4800
        # real pairs reaching the node among the flood: each answered, or dropped and counted
        # when the node fell behind (a loaded machine), none lost unaccounted
        assert formed >= 0.9 * (len(stamps) - 1), f"{formed} of {len(stamps) - 1} pairs formed"
        assert answered > 0 and answered + dropped == formed, (answered, dropped)
        assert int(health["errors_total"]) >= 0.9 * sent_bad  # counted, not silently lost
    finally:
        proc.stop()
