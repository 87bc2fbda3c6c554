"""Camera calibration YAML files (``camera_calibration_parsers``' format): written, read back,
read by PyYAML (a YAML 1.1 reader, as yaml-cpp is), and a file as ``camera_calibration`` writes
it read by our reader."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import yaml

from sepfm_ros.geometry.calibrated.camera import CalibrationError, camera_model
from sepfm_ros.ros.msgs.camera_yaml import (
    KEYS,
    camera_name,
    camera_yaml,
    parse_camera_yaml,
    read_camera_yaml,
    write_camera_yaml,
)

# a file in the layout camera_calibration (ost.yaml) and camera_calibration_parsers write
OST = """image_width: 640
image_height: 480
camera_name: narrow_stereo
camera_matrix:
  rows: 3
  cols: 3
  data: [ 521.6, 0., 316.9, 0., 522.8, 245.2, 0., 0., 1.]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [ 0.0876, -0.1824, 0.0019, -0.0005, 0.]
rectification_matrix:
  rows: 3
  cols: 3
  data: [ 1., 0., 0., 0., 1., 0., 0., 0., 1.]
projection_matrix:
  rows: 3
  cols: 4
  data: [ 530.0, 0., 316.0, 0., 0., 531.0, 246.0, 0., 0., 0., 1., 0.]
"""


def _model(seed: int):
    rng = np.random.default_rng(seed)
    K = np.array([[700 + rng.uniform(0, 50), 0, 320 + rng.uniform()], [0, 710, 240.5], [0, 0, 1]])
    D = np.array([-0.2, 0.05, 1.3e-5, -7e-6, 0.0])
    a = rng.uniform(-0.02, 0.02, 3)
    R = cv2.Rodrigues(a)[0]
    P = np.c_[K, [-K[0, 0] * 0.12, 0.0, 0.0]]
    return camera_model(K, D, "plumb_bob", R, P, 640, 480)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_round_trip_is_exact(tmp_path, seed):
    model = _model(seed)
    path = tmp_path / "right.yaml"
    write_camera_yaml(path, model, "/rig/right_camera_optical_frame")
    name, back = read_camera_yaml(path)
    assert name == "rig_right_camera_optical_frame"
    for f in ("K", "D", "R", "P"):
        assert np.array_equal(getattr(back, f), getattr(model, f)), f
    assert back.size == model.size and back.distortion_model == model.distortion_model


def test_layout_and_yaml_1_1_reader_sees_numbers():
    text = camera_yaml(_model(0), "left")
    assert [line.split(":")[0] for line in text.splitlines() if not line.startswith(" ")] == list(
        KEYS
    )
    doc = yaml.safe_load(text)  # PyYAML resolves YAML 1.1: "1e-05" would be a string
    for key in ("camera_matrix", "distortion_coefficients", "projection_matrix"):
        assert all(isinstance(v, float) for v in doc[key]["data"]), doc[key]
    assert doc["distortion_coefficients"] == {
        "rows": 1,
        "cols": 5,
        "data": pytest.approx([-0.2, 0.05, 1.3e-5, -7e-6, 0.0], abs=0, rel=0),
    }
    assert (doc["image_width"], doc["image_height"]) == (640, 480)


def test_reads_a_file_camera_calibration_wrote():
    name, model = parse_camera_yaml(OST)
    assert name == "narrow_stereo" and model.size == (640, 480)
    assert model.K[0, 0] == 521.6 and model.D[0] == 0.0876 and model.P[1, 2] == 246.0


def test_names_camera_info_manager_accepts():
    assert camera_name("left_camera_optical_frame") == "left_camera_optical_frame"
    assert camera_name("/stereo/left/image_raw") == "stereo_left_image_raw"
    assert camera_name("") == "camera"


@pytest.mark.parametrize(
    ("text", "says"),
    [
        ("[1, 2", "not YAML"),
        ("just text", "not a YAML mapping"),
        (OST.replace("projection_matrix", "projection"), "no 'projection_matrix'"),
        (OST.replace("cols: 4", "cols: 3"), "projection_matrix is 3x3 with 12 values"),
        (OST.replace("521.6", "zero"), "non-numeric"),
        (OST.replace("image_width: 640", "image_width: -1"), "not positive"),
    ],
)
def test_bad_files_give_clear_errors(text, says):
    with pytest.raises(CalibrationError, match=says):
        parse_camera_yaml(text, "f.yaml")


def test_missing_file_is_a_calibration_error(tmp_path):
    with pytest.raises(CalibrationError, match="cannot read"):
        read_camera_yaml(tmp_path / "none.yaml")
