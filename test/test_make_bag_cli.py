"""``sepfm_ros make_bag`` from ../shared/data: topics, stamps, encodings and ground truth."""

from __future__ import annotations

import json

import numpy as np
import pytest

from sepfm_ros.geometry import fundamental_from_cameras
from sepfm_ros.ros import make_bag
from sepfm_ros.ros.bags.reader import BagReader


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
    with BagReader(out) as bag:
        assert set(bag.topics) == {*image_topics, "/ground_truth/fundamental"}
        for topic in image_topics:
            msgs = [bag.deserialize(m) for m in bag.messages([topic])]
            assert len(msgs) == 4
            stamps = [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in msgs]
            assert np.allclose(np.diff(stamps), 0.2e9)  # --rate 5
            if encoding == "compressed":
                assert msgs[0].format.startswith("png") or "png" in msgs[0].format
            else:
                assert msgs[0].encoding == "bgr8" and msgs[0].step == 3 * msgs[0].width
        gts = [bag.deserialize(m) for m in bag.messages(["/ground_truth/fundamental"])]
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
