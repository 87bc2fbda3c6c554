"""The live node over real DDS: the node runs as a subprocess (``python -m sepfm_ros node``), this
test process publishes real images from ../shared/data with rclpy and checks what comes back.

One stereo node, one motion node and one compressed-transport node are started per module and
shared by the checks; shutdown gets nodes of its own. A unique ROS_DOMAIN_ID per session
(conftest ``ros_domain_id``) keeps concurrent runs apart.
"""

from __future__ import annotations

import ast
import os
import signal
import subprocess
import sys
import time

import cv2
import numpy as np
import pytest
from ground_truth import gt_fundamental, median_gt_inlier_error

rclpy = pytest.importorskip("rclpy")

from ros_helpers import (  # noqa: E402
    REPO,
    header,
    image_msg,
    next_stamp,
    send_pair,
    start_node,
)
from sensor_msgs.msg import CompressedImage, Image  # noqa: E402

from sepfm_msgs.msg import TwoViewEstimate  # noqa: E402
from sepfm_ros.geometry.epipolar import symmetric_epipolar_distance  # noqa: E402
from sepfm_ros.ros.msgs.headers import stamp_ns  # noqa: E402
from sepfm_ros.ros.msgs.image_conversion import numpy_to_compressed  # noqa: E402
from sepfm_ros.synthetic.sequences import pair_fundamental, stereo_sequence  # noqa: E402

KITTI_STEREO = [
    ("kitti_seq2/left/000000.png", "kitti_seq2/right/000000.png"),
    ("kitti_seq2/left/000020.png", "kitti_seq2/right/000020.png"),
]
TEMPLE_FRAMES = [f"templeRing/templeR{k:04d}.png" for k in (1, 2, 3, 4)]
KITTI_FRAMES = [f"kitti_seq2/left/{k:06d}.png" for k in (10, 11, 12)]


# --------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def images(shared_data):
    cache = {}

    def load(rel: str) -> np.ndarray:
        if rel not in cache:
            cache[rel] = cv2.imread(str(shared_data / rel), cv2.IMREAD_GRAYSCALE)
            assert cache[rel] is not None, rel
        return cache[rel]

    return load


@pytest.fixture(scope="module")
def stereo(ros, tmp_path_factory):
    ns = "/t_stereo"
    proc, client = start_node(
        "sepfm_stereo",
        tmp_path_factory.mktemp("stereo"),
        ros,
        {"left": (f"{ns}/left/image_raw", Image), "right": (f"{ns}/right/image_raw", Image)},
        "-r",
        f"left/image_raw:={ns}/left/image_raw",
        "-r",
        f"right/image_raw:={ns}/right/image_raw",
        "-p",
        "sync_slop_s:=0.005",
        "-p",
        "seed:=7",
        "-p",
        f"qos_overrides.{ns}/left/image_raw.subscription.reliability:=reliable",
        "-p",
        f"qos_overrides.{ns}/right/image_raw.subscription.reliability:=reliable",
    )
    yield proc, client
    proc.stop()


@pytest.fixture(scope="module")
def motion(ros, tmp_path_factory):
    proc, client = start_node(
        "sepfm_motion",
        tmp_path_factory.mktemp("motion"),
        ros,
        {"image": ("/t_motion/image_raw", Image)},
        "--params-file",  # the installed defaults first: later arguments override them
        str(REPO / "config" / "sepfm.yaml"),
        "-p",
        "mode:=motion",
        "-r",
        "image_raw:=/t_motion/image_raw",
    )
    yield proc, client
    proc.stop()


@pytest.fixture(scope="module")
def compressed(ros, tmp_path_factory):
    ns = "/t_comp"
    proc, client = start_node(
        "sepfm_comp",
        tmp_path_factory.mktemp("compressed"),
        ros,
        {
            "left": (f"{ns}/left/image_raw/compressed", CompressedImage),
            "right": (f"{ns}/right/image_raw/compressed", CompressedImage),
        },
        "-p",
        "image_transport:=compressed",
        "-r",
        f"left/image_raw/compressed:={ns}/left/image_raw/compressed",
        "-r",
        f"right/image_raw/compressed:={ns}/right/image_raw/compressed",
    )
    yield proc, client
    proc.stop()


def assert_accurate(shared_data, est, F, cloud, img_a, img_b):
    # F is published also when the estimator flags it (e.g. a dominant plane), with its code
    assert F is not None, est.status_text
    assert (est.status == TwoViewEstimate.STATUS_OK) == (est.status_text == "ok")
    pts_a = np.stack([cloud["u_a"], cloud["v_a"]], axis=1).astype(np.float64)
    pts_b = np.stack([cloud["u_b"], cloud["v_b"]], axis=1).astype(np.float64)
    assert est.matches == len(cloud)
    assert est.inliers == int(cloud["inlier"].sum())
    err, n_gt = median_gt_inlier_error(F, gt_fundamental(shared_data, img_a, img_b), pts_a, pts_b)
    assert n_gt >= 30, f"{img_a} -> {img_b}: only {n_gt} GT-inlier matches"
    assert err < 1.0, f"{img_a} -> {img_b}: median GT-inlier error {err:.3f} px"
    assert np.isclose(np.linalg.norm(F), 1.0)
    return err


# --------------------------------------------------------------------------- tests
def test_stereo_kitti_left_right_matches_ground_truth(stereo, images, shared_data):
    _, client = stereo
    for img_a, img_b in KITTI_STEREO:
        stamp = next_stamp()
        send_pair(client, image_msg(images(img_a), stamp), image_msg(images(img_b), stamp))
        values, F, cloud = client.wait_outputs(stamp)
        assert_accurate(shared_data, values, F, cloud, img_a, img_b)
        assert stamp_ns(values.stamp_a) == stamp_ns(values.stamp_b) == stamp
        assert values.method == "sep4" and values.features == "orb"
        assert values.hypotheses >= values.stage2_hypotheses > 0 and values.samples > 0
        assert values.coordinates == "image" and values.pose_kind == TwoViewEstimate.POSE_NONE
        assert (values.width_a, values.height_a) == images(img_a).shape[::-1]
        timings = {t.stage: t.ms for t in values.timings}
        ms = {s: timings[s] for s in ("decode", "features", "match", "estimate")}
        assert all(v > 0.0 for v in ms.values()), ms
        assert timings["total"] >= ms["features"] + ms["match"] + ms["estimate"]
        assert {"wait", "queue", "latency", "publish"} <= set(timings)
        assert values.header.frame_id == "cam" and values.frame_id_b == "cam"


def test_stereo_every_encoding(stereo, images, shared_data):
    _, client = stereo
    img_a, img_b = KITTI_STEREO[0]
    encodings = ["mono8", "mono16", "8UC1", "8UC3", "8UC4", "16UC1", "bgr8", "rgb8", "bgra8"]
    encodings += ["rgba8", "bayer_rggb8", "bayer_bggr8", "bayer_gbrg8", "bayer_grbg8"]
    encodings += ["yuv422", "yuv422_yuy2"]
    for k, encoding in enumerate(encodings):
        stamp = next_stamp()
        pad = 4 * (k % 2)  # every other one with row padding
        left = image_msg(images(img_a), stamp, encoding, pad)
        right = image_msg(images(img_b), stamp, encoding, pad)
        send_pair(client, left, right)
        values, F, cloud = client.wait_outputs(stamp)
        assert_accurate(shared_data, values, F, cloud, img_a, img_b)


def test_stereo_sync_with_jittered_stamps(stereo, images):
    _, client = stereo
    img_a, img_b = KITTI_STEREO[1]
    # right 3 ms after left (inside the 5 ms slop), arriving first: paired, header = left's
    stamp = next_stamp()
    send_pair(
        client,
        image_msg(images(img_a), stamp),
        image_msg(images(img_b), stamp + 3_000_000),
        right_first=True,
    )
    values, F, _ = client.wait_outputs(stamp)
    assert np.isclose(np.linalg.norm(F), 1.0)
    assert stamp_ns(values.stamp_b) == stamp + 3_000_000
    # right 8 ms after left (outside the slop): never paired
    lone = next_stamp()
    send_pair(client, image_msg(images(img_a), lone), image_msg(images(img_b), lone + 8_000_000))
    # the next good pair is answered, the out-of-slop one never was
    stamp = next_stamp()
    send_pair(client, image_msg(images(img_a), stamp), image_msg(images(img_b), stamp - 2_000_000))
    client.wait_outputs(stamp)
    # answers come in order on one topic: had the lone pair been paired, it would be here now
    with client.lock:
        assert lone not in client.info and lone + 8_000_000 not in client.info
    health = client.latest_health(after=0.0)
    assert int(health["sync_unmatched"]) >= 2


def test_runtime_parameter_change_accepted_and_rejected(stereo, images):
    _, client = stereo
    img_a, img_b = KITTI_STEREO[0]
    ok, reason = client.set_parameter("max_matches", 150)
    assert ok, reason
    stamp = next_stamp()
    send_pair(client, image_msg(images(img_a), stamp), image_msg(images(img_b), stamp))
    values, _, cloud = client.wait_outputs(stamp, need_f=False)  # F or a reason, both fine here
    assert values.matches == 150 and len(cloud) == 150
    for name, value, text in [
        ("features", "surf", "features must be one of"),
        ("max_features", -5, "max_features"),
        ("threshold_px", 1000.0, "threshold_px"),
        ("method", "magic", "method must be one of"),
        ("mode", "motion", "read-only"),
    ]:
        ok, reason = client.set_parameter(name, value)
        assert not ok, f"{name}={value!r} was accepted"
        assert text in reason, reason
    ok, _ = client.set_parameter("max_features", "many")  # wrong type
    assert not ok
    assert client.get_parameter("features") == "orb"
    assert client.get_parameter("max_features") == 1000
    assert client.get_parameter("mode") == "stereo"
    assert client.get_parameter("max_matches") == 150
    ok, reason = client.set_parameter("max_matches", 0)
    assert ok, reason
    stamp = next_stamp()
    send_pair(client, image_msg(images(img_a), stamp), image_msg(images(img_b), stamp))
    values, F, _ = client.wait_outputs(stamp)
    assert values.matches > 150


def test_malformed_messages_are_skipped_counted_and_logged_once(stereo, images):
    proc, client = stereo
    img_a, img_b = KITTI_STEREO[0]
    good = image_msg(images(img_a), 0)
    bad = []
    short = image_msg(images(img_a), next_stamp())
    short.data = bytes(short.data)[:-100]
    bad.append(("left", short))
    bad.append(("left", image_msg(images(img_a), next_stamp())))  # made short below
    bad[-1][1].data = bytes(10)
    zero = Image(header=header(next_stamp()), height=0, width=0, encoding="mono8", step=0)
    bad.append(("right", zero))
    unknown = image_msg(images(img_a), next_stamp())
    unknown.encoding = "h264"
    bad.append(("right", unknown))
    step = image_msg(images(img_a), next_stamp())
    step.step = good.width - 1
    bad.append(("left", step))
    for key, msg in bad:
        client.publish(key, msg)
    # good pairs are still answered
    stamp = next_stamp()
    send_pair(client, image_msg(images(img_a), stamp), image_msg(images(img_b), stamp))
    values, F, _ = client.wait_outputs(stamp)
    assert F is not None and values.status == TwoViewEstimate.STATUS_OK
    health = client.latest_health(after=1.2)
    assert int(health["errors_short_data"]) >= 2
    assert int(health["errors_zero_size"]) >= 1
    assert int(health["errors_unknown_encoding"]) >= 1
    assert int(health["errors_bad_step"]) >= 1
    log = proc.output()
    assert log.count("skipping bad input (short_data)") == 1, log
    assert "Traceback" not in log
    assert proc.proc.poll() is None


def test_stereo_rig_of_two_cameras_of_different_sizes(stereo):
    """A rig pairing two different cameras (left 480x360, right 400x300, each its own K): F
    relates any two views, so the pair is answered, not refused, and F is accurate."""
    before = stereo[1].latest_health(after=1.2)
    for frame in stereo_sequence(n_frames=2, right_size=(400, 300), seed=3):
        stamp = next_stamp()
        left, right = frame.images
        send_pair(stereo[1], image_msg(left, stamp), image_msg(right, stamp))
        values, F, cloud = stereo[1].wait_outputs(stamp)
        assert values.status_text == "ok" and (values.width_b, values.height_b) == (400, 300)
        F_gt = pair_fundamental(*frame.cameras)
        pts_a = np.stack([cloud["u_a"], cloud["v_a"]], 1).astype(float)
        pts_b = np.stack([cloud["u_b"], cloud["v_b"]], 1).astype(float)
        pos = symmetric_epipolar_distance(F_gt, pts_a, pts_b) < 1.0
        assert pos.sum() >= 100
        assert np.median(symmetric_epipolar_distance(F, pts_a[pos], pts_b[pos])) < 1.0
    health = stereo[1].latest_health(after=1.2)
    assert int(health.get("errors_size_change", 0)) == int(before.get("errors_size_change", 0))


def test_failed_estimate_publishes_reason_and_no_f(stereo, images):
    _, client = stereo
    blank = np.full((376, 1241), 90, np.uint8)
    stamp = next_stamp()
    send_pair(client, image_msg(blank, stamp), image_msg(blank, stamp))
    values, F, cloud = client.wait_outputs(stamp, need_f=False)
    assert F is None and not values.has_f and not np.any(values.f)
    assert values.status not in (TwoViewEstimate.STATUS_OK, TwoViewEstimate.STATUS_BAD_INPUT)
    assert values.status_text != "ok" and values.bad_input_kind == ""
    assert np.isnan(values.inlier_error_px) and len(cloud) == values.matches


def test_debug_image_and_health(stereo, images):
    _, client = stereo
    client.subscribe_debug()
    try:
        img_a, img_b = KITTI_STEREO[0]
        deadline = time.monotonic() + 20.0
        while time.monotonic() < deadline:
            stamp = next_stamp()
            send_pair(client, image_msg(images(img_a), stamp), image_msg(images(img_b), stamp))
            client.wait_info(stamp)
            time.sleep(0.2)
            with client.lock:
                if client.debug:
                    break
        with client.lock:
            assert client.debug, "no ~/debug_image although subscribed"
            msg = list(client.debug.values())[-1]
        assert msg.encoding == "bgr8" and msg.width == 2 * 1241 and msg.height == 376
    finally:
        client.unsubscribe_debug()
    health = client.latest_health(after=0.0)
    for key in ("input_rate_left_hz", "output_rate_hz", "synchronized_pairs", "dropped_pairs"):
        assert key in health
    assert 0.0 < float(health["latency_p50_ms"]) < 10_000.0
    assert 0.0 < float(health["latency_p95_ms"]) < 10_000.0


def test_overload_drops_frames_instead_of_queueing(stereo, images):
    _, client = stereo
    img_a, img_b = KITTI_STEREO[0]
    before = client.latest_health(after=0.0)
    left, right = images(img_a), images(img_b)
    stamps = []
    for _ in range(25):
        stamp = next_stamp()
        stamps.append(stamp)
        send_pair(client, image_msg(left, stamp), image_msg(right, stamp))
        time.sleep(0.005)  # a 200 pairs/s camera: far faster than the node can estimate
    client.wait_info(stamps[-1])  # the newest pair is always processed
    after = client.latest_health(after=1.2)
    with client.lock:
        answered = sum(s in client.info for s in stamps)
    dropped = int(after["dropped_pairs"]) - int(before["dropped_pairs"])
    paired = int(after["synchronized_pairs"]) - int(before["synchronized_pairs"])
    assert answered < 25 and dropped > 0
    # every pair that reached the node was either answered or dropped-and-counted (pairs the
    # sensor-data QoS history overwrote before the executor took them never reached it)
    assert answered + dropped == paired


def test_pairs_delivered_together_to_an_idle_node_are_all_answered(stereo, images):
    # A transport delay (a reliable reader recovering a lost fragment, a sender catching up)
    # delivers two pairs at once to a node that is idle: it is not busy, so neither is dropped.
    _, client = stereo
    img_a, img_b = KITTI_STEREO[0]
    left, right = images(img_a), images(img_b)
    before = client.latest_health(after=0.0)
    stamps = []
    for _ in range(6):
        time.sleep(0.6)  # bursts 0.6 s apart; the node answered the last one, so it is idle
        burst = [next_stamp(), next_stamp()]
        for stamp in burst:
            send_pair(client, image_msg(left, stamp), image_msg(right, stamp))
        for stamp in burst:
            client.wait_info(stamp, timeout=15.0)
        stamps += burst
    after = client.latest_health(after=1.2)
    assert int(after["dropped_pairs"]) == int(before["dropped_pairs"])
    with client.lock:
        assert all(s in client.info for s in stamps)


def test_motion_templering_and_kitti_consecutive_frames(motion, images, shared_data):
    _, client = motion
    before = client.latest_health(after=0.0)
    errors = []
    for frames in (TEMPLE_FRAMES, KITTI_FRAMES):
        prev = None
        for rel in frames:
            stamp = next_stamp()
            client.publish("image", image_msg(images(rel), stamp))
            if prev is not None:
                prev_rel, prev_stamp = prev
                if images(prev_rel).shape != images(rel).shape:
                    # first KITTI frame after a templeRing frame: a frame-size change, answered
                    # with a failure record
                    failed = client.wait_info(stamp)
                    assert failed.status == TwoViewEstimate.STATUS_BAD_INPUT
                    assert failed.bad_input_kind == "size_change" and not failed.has_f
                    assert (failed.width_b, failed.height_b) == images(rel).shape[::-1]
                else:
                    values, F, cloud = client.wait_outputs(stamp)
                    errors.append(assert_accurate(shared_data, values, F, cloud, prev_rel, rel))
                    assert stamp_ns(values.stamp_a) == prev_stamp
            prev = (rel, stamp)
    assert len(errors) == len(TEMPLE_FRAMES) - 1 + len(KITTI_FRAMES) - 1
    health = client.latest_health(after=1.2)
    assert int(health["errors_size_change"]) == 1
    # every frame's features computed once: as image b of one pair, then from the cache as
    # image a of the next (the templeRing -> KITTI pair fails on size before detection)
    n_frames = len(TEMPLE_FRAMES) + len(KITTI_FRAMES)
    detected = int(health["images_detected"]) - int(before["images_detected"])
    cached = int(health["images_features_cached"]) - int(before["images_features_cached"])
    assert (detected, cached) == (n_frames, n_frames - 4)


def test_compressed_transport_jpeg_and_png(compressed, images, shared_data):
    _, client = compressed
    img_a, img_b = KITTI_STEREO[0]
    for fmt in ("jpeg", "png"):
        stamp = next_stamp()
        left = numpy_to_compressed(images(img_a), fmt, header(stamp))
        right = numpy_to_compressed(images(img_b), fmt, header(stamp))
        send_pair(client, left, right)
        values, F, cloud = client.wait_outputs(stamp)
        assert_accurate(shared_data, values, F, cloud, img_a, img_b)
    stamp = next_stamp()
    broken = CompressedImage(header=header(stamp), format="jpeg", data=b"\xff\xd8 not really")
    send_pair(client, broken, numpy_to_compressed(images(img_b), "jpeg", header(stamp)))
    health = client.latest_health(after=1.2)
    assert int(health["errors_bad_compressed"]) == 1


def readme_consumer(topic: str) -> str:
    """README's five-line consumer, subscribed to ``topic``."""
    text = (REPO / "README.md").read_text()
    block = text.split("<!-- consumer:begin -->")[1].split("<!-- consumer:end -->")[0]
    code = block.split("```python\n")[1].split("```")[0]
    assert len(code.strip().splitlines()) == 5, code
    assert '"/sepfm/estimate"' in code
    return code.replace('"/sepfm/estimate"', repr(topic))


def consumer_answers(path) -> list[tuple[str, np.ndarray | None]]:
    """The consumer's lines: (status text, F (3, 3) or None)."""
    out = []
    for line in path.read_text().splitlines():
        status, f = line.rsplit(" ", 1) if line.endswith("None") else line.split(" [", 1)
        out.append((status, None if f == "None" else np.array(ast.literal_eval("[" + f))))
    return out


def test_typed_answers_reach_a_consumer_in_another_process(stereo, tmp_path):
    """README's consumer in its own process gets one TwoViewEstimate per pair over DDS, with F
    as 3x3 from ``msg.f``, the F the node answered."""
    _, client = stereo
    script, out = tmp_path / "consumer.py", tmp_path / "consumer.out"
    script.write_text(readme_consumer("/sepfm_stereo/estimate"))
    frames = stereo_sequence(n_frames=8, size=(480, 360), seed=11)
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    with open(out, "w") as log:
        consumer = subprocess.Popen([sys.executable, str(script)], stdout=log, stderr=log, env=env)
    try:
        # warm-up pairs until the consumer prints (discovery and matching take a moment)
        for frame in frames[:5]:
            stamp = next_stamp()
            send_pair(client, *(image_msg(im, stamp) for im in frame.images))
            client.wait_info(stamp)
            deadline = time.monotonic() + 5.0
            while not out.read_text() and time.monotonic() < deadline:
                assert consumer.poll() is None, out.read_text()
                time.sleep(0.05)
            if out.read_text():
                break
        assert out.read_text(), "the consumer received nothing"
        sent = []
        for frame in frames[5:]:
            stamp = next_stamp()
            send_pair(client, *(image_msg(im, stamp) for im in frame.images))
            _, F, _ = client.wait_outputs(stamp)
            sent.append(F)
        deadline = time.monotonic() + 20.0
        while time.monotonic() < deadline:
            got = [f for _, f in consumer_answers(out) if f is not None]
            if got and np.array_equal(got[-1], sent[-1]):
                break
            time.sleep(0.05)
        answers = consumer_answers(out)
    finally:
        consumer.kill()  # how the consumer ends is not under test
        consumer.wait()
    got = [f for _, f in answers]
    assert all(status == "ok" for status, _ in answers[-3:]), answers
    for F, received in zip(sent, got[-3:], strict=True):  # in order, each once, exact
        assert received.shape == (3, 3)
        np.testing.assert_array_equal(received, F)
    for F in sent:
        assert sum(f is not None and np.array_equal(f, F) for f in got) == 1


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_clean_shutdown(ros, tmp_path, sig):
    name = f"sepfm_shutdown_{sig.name.lower()}"
    proc, _ = start_node(
        name, tmp_path, ros, {"image": (f"/{name}/in", Image)}, "-r", f"image_raw:=/{name}/in",
        "-p", "mode:=motion",
    )  # fmt: skip
    code = proc.stop(sig, timeout=15.0)
    log = proc.output()
    assert code == 0, log
    assert "Traceback" not in log, log
