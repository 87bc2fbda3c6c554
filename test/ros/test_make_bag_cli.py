"""``sepfm_ros make_bag`` from ../shared/data: topics, stamps, encodings and ground truth."""

from __future__ import annotations

import json

import numpy as np
import pytest

from sepfm_ros.geometry import fundamental_from_cameras
from sepfm_ros.ros.bags.reader import BagReader
from sepfm_ros.ros.commands import make_bag
from sepfm_ros.ros.msgs.image_conversion import message_to_numpy


@pytest.mark.parametrize(
    "sequence,encoding,image_topics",
    [
        ("kitti_stereo", "bgr8", ["/left/image_raw", "/right/image_raw"]),
        ("templeRing", "compressed", ["/image_raw/compressed"]),
    ],
)
def test_make_bag_from_shared_data(sequence, encoding, image_topics, shared_data, tmp_path):
    out = tmp_path / "bag"
    args = ["--shared", sequence, "--data", str(shared_data), "-o", str(out), "--rate", "5",
            "--encoding", encoding, "--start", "2", "--count", "4"]  # fmt: skip
    assert make_bag.main(args) == 0
    info_topics = {t.split("/image_raw")[0] + "/camera_info" for t in image_topics}
    with BagReader(out) as bag:
        assert set(bag.topics) == {*image_topics, *info_topics, "/ground_truth/fundamental"}
        for topic in image_topics:
            msgs = [bag.deserialize(m) for m in bag.messages([topic])]
            assert len(msgs) == 4
            stamps = [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in msgs]
            assert np.allclose(np.diff(stamps), 0.2e9)  # --rate 5
            if encoding == "compressed":
                assert msgs[0].format.startswith("png") or "png" in msgs[0].format
            else:
                assert msgs[0].encoding == "bgr8" and msgs[0].step == 3 * msgs[0].width
            infos = [bag.deserialize(m) for m in bag.messages([_info_topic(topic)])]
            # one camera_info per image, same stamp and frame id, plumb_bob with D = 0
            assert [(i.header.stamp, i.header.frame_id) for i in infos] == [
                (m.header.stamp, m.header.frame_id) for m in msgs
            ]
            assert infos[0].distortion_model == "plumb_bob"
            assert list(infos[0].d) == [0.0] * 5
            shape = message_to_numpy(msgs[0], "mono8").shape
            assert (infos[0].height, infos[0].width) == shape
        gts = [bag.deserialize(m) for m in bag.messages(["/ground_truth/fundamental"])]
        info = {t: bag.deserialize(next(bag.messages([t]))) for t in sorted(info_topics)}
    # stereo: one GT per frame; motion: one per consecutive pair
    assert len(gts) == (4 if sequence == "kitti_stereo" else 3)
    F = np.frombuffer(bytes(gts[0].data), dtype=np.float64).reshape(3, 3)
    assert gts[0].encoding == "64FC1" and np.isclose(np.linalg.norm(F), 1.0)
    cams = json.loads((shared_data / "cameras.json").read_text())
    if sequence == "kitti_stereo":
        a, b = "kitti_seq2/left/000002.png", "kitti_seq2/right/000002.png"
    else:
        a, b = "templeRing/templeR0003.png", "templeRing/templeR0004.png"
    expected = fundamental_from_cameras(np.array(cams[a]), np.array(cams[b]))
    assert min(np.abs(F - expected).max(), np.abs(F + expected).max()) < 1e-9
    # camera_info: K of the frame's camera (P = K [R | t] in cameras.json), R = I (rectified
    # KITTI, or one camera), P = [K | 0], and the right camera's Tx = -fx * baseline
    P_a = np.array(cams[a])
    first = info["/left/camera_info" if sequence == "kitti_stereo" else "/camera_info"]
    K = np.array(first.k).reshape(3, 3)
    np.testing.assert_allclose(np.array(first.r).reshape(3, 3), np.eye(3), atol=1e-12)
    np.testing.assert_allclose(np.array(first.p).reshape(3, 4)[:, :3], K, atol=1e-9)
    assert np.array(first.p).reshape(3, 4)[:, 3].tolist() == [0.0, 0.0, 0.0]
    # K is the intrinsics of frame 2's camera: K^-1 P[:, :3] is a scaled rotation
    M = np.linalg.solve(K, P_a[:, :3])
    MMt = M @ M.T
    np.testing.assert_allclose(MMt / MMt[0, 0], np.eye(3), atol=1e-6)
    assert K[0, 0] > 0 and K[1, 1] > 0 and K[2, 2] == 1.0
    if sequence == "kitti_stereo":
        right = np.array(info["/right/camera_info"].p).reshape(3, 4)
        fx = K[0, 0]
        baseline = -right[0, 3] / fx
        assert 0.5 < baseline < 0.6  # KITTI's stereo baseline, 0.54 m
        np.testing.assert_allclose(right[1:, 3], 0.0, atol=1e-9)
        # the two camera_infos give the GT F: x_r^T F x_l = 0 for rectified cameras
        P_r = right
        P_l = np.array(first.p).reshape(3, 4)
        F_info = fundamental_from_cameras(P_l, P_r)
        # F from camera_info agrees with the GT F on a grid of left points' epipolar lines
        assert min(np.abs(F_info / np.linalg.norm(F_info) - F).max(),
                   np.abs(F_info / np.linalg.norm(F_info) + F).max()) < 1e-3  # fmt: skip


def _info_topic(image_topic: str) -> str:
    return image_topic.split("/image_raw")[0] + "/camera_info"
