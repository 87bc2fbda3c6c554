"""The live node's transport, over real DDS: the ``image_transport`` parameter (its old name
``transport`` still read, with a warning), ``~/debug_image/compressed``, camera_info matched to
each image by stamp (an image without one counted), and frames missing from the camera's stamp
sequence counted and reported in /diagnostics.

One motion-mode node started with the old name ``transport:=compressed``, fed JPEG frames of the
KITTI sequence one at a time (each answered before the next), so every pair is answered.
"""

from __future__ import annotations

import time

import cv2
import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from diagnostic_msgs.msg import DiagnosticStatus  # noqa: E402
from ros_helpers import RELIABLE, header, start_node  # noqa: E402
from sensor_msgs.msg import CameraInfo, CompressedImage  # noqa: E402

from sepfm_ros.ros.bags.synthesis import camera_info_message, camera_infos  # noqa: E402
from sepfm_ros.ros.msgs.headers import stamp_ns  # noqa: E402
from sepfm_ros.ros.msgs.image_conversion import numpy_to_compressed  # noqa: E402

NS = "/t_tr"
NODE = "sepfm_tr"
T0 = 1_700_300_000 * 10**9
PERIOD = 100_000_000  # 10 Hz
SIZE = (1241, 376)
WARN = int.from_bytes(DiagnosticStatus.WARN, "little")


@pytest.fixture(scope="module")
def node(ros, tmp_path_factory, shared_data):
    proc, client = start_node(
        NODE,
        tmp_path_factory.mktemp("transport"),
        ros,
        {
            "image": (f"{NS}/image_raw/compressed", CompressedImage),
            "info": (f"{NS}/camera_info", CameraInfo),
        },
        "-p",
        "mode:=motion",
        "-p",
        "transport:=compressed",  # the old name: read, with a warning
        "-r",
        f"image_raw:={NS}/image_raw",
    )
    debug: dict[int, CompressedImage] = {}
    sub = ros.node.create_subscription(
        CompressedImage,
        f"/{NODE}/debug_image/compressed",
        lambda m: debug.__setitem__(stamp_ns(m.header.stamp), m),
        RELIABLE,
    )
    cams = __import__("json").loads((shared_data / "cameras.json").read_text())
    calib = camera_infos((np.asarray(cams["kitti_seq2/left/000000.png"]),), SIZE)[0]
    time.sleep(0.5)
    yield proc, client, debug, calib
    ros.node.destroy_subscription(sub)
    proc.stop()


def _frame(shared_data, k: int) -> np.ndarray:
    path = shared_data / f"kitti_seq2/left/{k % 40:06d}.png"
    return cv2.imread(str(path), cv2.IMREAD_COLOR)


def _send(client, shared_data, calib, k: int, info_offsets_ns=(0,), junk_after=False) -> int:
    """Frame ``k`` (stamp T0 + k periods) after its camera_info stamped at each of
    ``info_offsets_ns`` from it; ``junk_after``: then an unusable camera_info (K = 0) stamped
    40 ms later (outside the slop), the latest one when the frame is answered."""
    stamp = T0 + k * PERIOD
    for offset in info_offsets_ns:
        client.publish("info", camera_info_message(calib, SIZE, header(stamp + offset)))
    if junk_after:
        junk = camera_info_message(calib, SIZE, header(stamp + 40_000_000))
        junk.k = [0.0] * 9
        junk.p = [0.0] * 12
        client.publish("info", junk)
    time.sleep(0.05)  # the camera_info arrives before the image it belongs to
    msg = numpy_to_compressed(_frame(shared_data, k), "jpeg", header(stamp))
    client.publish("image", msg)
    return stamp


def _health(client) -> dict[str, str]:
    return client.latest_health(after=1.5)


def test_old_name_transport_sets_image_transport_with_a_warning(node):
    proc, client, _, _ = node
    # connected at all: the node subscribed to <image_raw>/compressed
    assert client.get_parameter("image_transport") == "compressed"
    log = proc.output()
    assert "parameter transport is renamed image_transport" in log, log


def test_camera_info_matched_by_stamp_and_debug_image_compressed(node, shared_data):
    proc, client, debug, calib = node
    stamps = []
    for k in range(8):
        # the frame's own camera_info, then a later unusable one: by stamp, the good one
        stamps.append(_send(client, shared_data, calib, k, junk_after=True))
        if k:
            client.wait_info(stamps[-1])
    values = _health(client)
    assert int(values["images_without_camera_info"]) == 0, values
    assert int(values.get("errors_camera_info_invalid", 0)) == 0, values
    # ~/debug_image/compressed: a JPEG of the drawn pair for every answer while subscribed
    deadline = time.monotonic() + 30
    while not all(s in debug for s in stamps[1:]) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert all(s in debug for s in stamps[1:]), sorted(debug)
    msg = debug[stamps[-1]]
    assert msg.format == "bgr8; jpeg compressed bgr8"
    canvas = cv2.imdecode(np.frombuffer(bytes(msg.data), np.uint8), cv2.IMREAD_COLOR)
    assert canvas is not None and canvas.shape[0] >= SIZE[1] and canvas.shape[1] >= SIZE[0]
    assert int(values["debug_image_subscribers"]) >= 1


def test_image_without_matching_camera_info_is_counted(node, shared_data):
    proc, client, _, calib = node
    before = int(_health(client)["images_without_camera_info"])
    for k in range(20, 25):
        # camera_info stamped 30 ms after its image: outside sync_slop_s (5 ms)
        client.wait_info(_send(client, shared_data, calib, k, info_offsets_ns=(30_000_000,)))
    values = _health(client)
    assert int(values["images_without_camera_info"]) - before == 5, values
    assert "no camera_info on /t_tr/camera_info stamped within sync_slop_s" in proc.output()


def test_frames_missing_from_the_stamp_sequence_are_counted_and_warned(node, shared_data):
    _, client, _, calib = node
    before = int(_health(client)["frames_missing"])
    # the camera's frames 40, 43, 46, ... arrive (after a pause): two of every three missing
    for k in range(40, 59, 3):
        client.wait_info(_send(client, shared_data, calib, k))
    values = _health(client)
    assert int(values["frames_missing"]) - before == 2 * 6, values
    assert float(values["frames_missing_share_image"]) > 0
    with client.lock:
        log = list(client.health_log)
    warned = [m for _, level, m in log if level == WARN and "missing from the camera stamp" in m]
    assert warned, log[-3:]


def test_old_name_in_process_parameters_warns():
    """``process``/``demo`` take the node's ``-p`` items: the old name sets image_transport."""
    from sepfm_ros.ros.session.parameters import given_params

    with pytest.warns(FutureWarning, match="parameter transport is renamed image_transport"):
        given = given_params(["transport:=compressed"])
    assert given.values["image_transport"] == "compressed"
    assert "image_transport" in given.given and "transport" not in given.values
