"""The renderer's ground truth is exact, and the committed bags are what the script makes."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from sepfm_ros.demo import bundled_bags_dir
from sepfm_ros.ros.bags.reader import BagReader
from sepfm_ros.ros.bags.synthesis import bag_messages, synthetic_frames
from sepfm_ros.ros.bags.types import TYPESTORE
from sepfm_ros.ros.msgs.image_conversion import message_to_numpy
from sepfm_ros.synthetic.scene import Camera, Plane, Scene, intrinsics, look_at, render
from sepfm_ros.synthetic.sequences import pair_fundamental, stereo_sequence


def test_rendered_point_lands_where_the_camera_projects_it():
    # a white square texture with one bright texel block; its image centroid must be the
    # projection of the block's world centre (sub-pixel), for a tilted plane and camera
    tex = np.zeros((41, 41), np.uint8)
    tex[18:23, 18:23] = 255
    plane = Plane(
        origin=np.array([-0.4, -0.3, 5.0]),
        u=np.array([0.02, 0.0, 0.004]),
        v=np.array([0.0, 0.02, 0.002]),
        texture=tex,
    )
    size = (160, 120)
    R, t = look_at((0.3, -0.1, 0.0), (0.0, 0.0, 5.0))
    cam = Camera(intrinsics(size, 40.0), R, t, size)
    img = render(Scene((plane,), background=0), cam, supersample=4).astype(np.float64)
    ys, xs = np.mgrid[0 : size[1], 0 : size[0]]
    centroid = np.array([(img * xs).sum(), (img * ys).sum()]) / img.sum()
    X = plane.origin + 20 * plane.u + 20 * plane.v
    x = cam.P @ np.append(X, 1.0)
    np.testing.assert_allclose(centroid, x[:2] / x[2], atol=0.05)


def test_ground_truth_fundamental_is_exact():
    frames = stereo_sequence(2, size=(160, 120))
    rng = np.random.default_rng(0)
    for f in frames:
        a, b = f.cameras
        F = pair_fundamental(a, b)
        X = np.column_stack([rng.uniform(-3, 3, (50, 2)), rng.uniform(4, 14, 50), np.ones(50)])
        xa, xb = (a.P @ X.T).T, (b.P @ X.T).T
        xa, xb = xa / xa[:, 2:], xb / xb[:, 2:]
        lines = (F @ xa.T).T
        d = np.abs(np.sum(xb * lines, axis=1)) / np.hypot(lines[:, 0], lines[:, 1])
        assert d.max() < 1e-9


def _load_script():
    path = Path(__file__).resolve().parents[2] / "scripts" / "make_bundled_bags.py"
    spec = importlib.util.spec_from_file_location("make_bundled_bags", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize(
    "name,kind,n,encoding",
    [
        ("synthetic_stereo", "stereo", 12, "mono8"),
        ("synthetic_motion", "motion", 13, "compressed"),
    ],
)
def test_bundled_bags_are_reproducible(name, kind, n, encoding):
    script = _load_script()
    RATE_HZ, SPECS = script.RATE_HZ, script.SPECS
    assert SPECS[name] == (kind, n, encoding)
    mode, frames = synthetic_frames(kind, n, seed=0)
    fresh = sorted(
        (t, s, _content(ty, d)) for t, ty, s, d in bag_messages(mode, frames, RATE_HZ, encoding)
    )
    with BagReader(bundled_bags_dir() / name) as reader:
        stored = sorted(
            (m.topic, m.log_time_ns, _content(m.msgtype, m.data)) for m in reader.messages()
        )
    # compared field by field (CDR padding bytes are not initialised by the serializer), pixels
    # within 1 grey level (another OpenCV build may round a warp differently)
    assert [(t, s, c[:-1]) for t, s, c in stored] == [(t, s, c[:-1]) for t, s, c in fresh]
    for (_, _, a), (_, _, b) in zip(stored, fresh, strict=True):
        if a[-1].dtype == np.uint8:
            assert np.abs(a[-1].astype(int) - b[-1].astype(int)).max() <= 1
        else:
            np.testing.assert_allclose(a[-1], b[-1], rtol=0, atol=1e-12)


def _content(msgtype: str, data: bytes) -> tuple:
    """(stamp, frame_id, layout..., pixels, F or camera matrices) of a message in a bag."""
    msg = TYPESTORE.deserialize_cdr(data, msgtype)
    fields: list = [msg.header.stamp.sec, msg.header.stamp.nanosec, msg.header.frame_id]
    if msgtype.endswith("CameraInfo"):
        fields += [msg.height, msg.width, msg.distortion_model]
        fields += [np.concatenate([msg.d, msg.k, msg.r, msg.p])]
    elif msgtype.endswith("CompressedImage"):
        fields += [msg.format, message_to_numpy(msg, "bgr8")]
    elif msg.encoding == "64FC1":
        fields += [msg.height, msg.width, np.frombuffer(bytes(msg.data), "<f8")]
    else:
        fields += [msg.height, msg.width, msg.encoding, message_to_numpy(msg, "mono8")]
    return tuple(fields)
