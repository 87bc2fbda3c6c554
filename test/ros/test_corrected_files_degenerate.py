"""``--write-corrected`` after a degenerate window (:func:`write_corrected`, no bag): a knocked
rig whose matches all lie on a small poster gets no camera file, and ``correction.json`` and the
printed line say why; camera files an earlier run wrote there go."""

from __future__ import annotations

import json

import cv2
import numpy as np

from sepfm_ros.geometry.calibrated.calibration_check import StereoCalibration
from sepfm_ros.geometry.calibrated.camera import camera_model
from sepfm_ros.geometry.calibrated.correction import (
    CorrectionConfig,
    CorrectionWindow,
    estimate_correction,
)
from sepfm_ros.ros.msgs.camera_yaml import write_camera_yaml
from sepfm_ros.ros.offline.corrected_files import write_corrected
from sepfm_ros.ros.offline.rig_check import CheckRun

SIZE = (640, 480)
K = np.array([[600.0, 0.0, 320.0], [0.0, 600.0, 240.0], [0.0, 0.0, 1.0]])
T = np.array([-0.12, 0.0, 0.0])


def _models():
    """A parallel raw rig without distortion, 0.12 m baseline."""
    R1, R2, P1, P2 = cv2.stereoRectify(K, None, K, None, SIZE, np.eye(3), T.reshape(3, 1))[:4]
    return (
        camera_model(K, np.zeros(5), "plumb_bob", R1, P1, *SIZE),
        camera_model(K, np.zeros(5), "plumb_bob", R2, P2, *SIZE),
    )


def _poster_window(knock_deg: float, pairs: int = 20, seed: int = 0) -> CorrectionWindow:
    """Matches of a 0.8 x 0.6 m poster 5 m ahead (0.3 px noise), b pitched by ``knock_deg``."""
    dR = cv2.Rodrigues(np.array([np.radians(knock_deg), 0.0, 0.0]))[0]
    window = CorrectionWindow(40)
    for k in range(pairs):
        rng = np.random.default_rng(seed * 1000 + k)
        X = np.stack(
            [rng.uniform(-0.4, 0.4, 300), rng.uniform(-0.3, 0.3, 300), np.full(300, 5.0)], axis=1
        )
        xa = cv2.projectPoints(X, np.zeros(3), np.zeros(3), K, None)[0].reshape(-1, 2)
        xb = cv2.projectPoints(X, cv2.Rodrigues(dR)[0], dR @ T, K, None)[0].reshape(-1, 2)
        window.add(xa + rng.normal(0, 0.3, xa.shape), xb + rng.normal(0, 0.3, xb.shape))
    return window


def test_a_degenerate_window_writes_no_camera_files_and_says_why(tmp_path):
    models = _models()
    calib = StereoCalibration.from_models(*models)
    result = estimate_correction(calib, _poster_window(0.5), CorrectionConfig())
    assert result.correction is None
    assert result.reason.startswith("degenerate window: the matches span"), result.reason
    out = tmp_path / "out"
    out.mkdir()
    for name, model in zip(("left.yaml", "right.yaml"), models, strict=True):  # an earlier run's
        write_camera_yaml(out / name, model, name[:-5])
    (out / "correction.json").write_text(json.dumps({"files": ["left.yaml", "right.yaml"]}))
    run = CheckRun(
        rows=[],
        topics=("/left/image_raw", "/right/image_raw"),
        info_topics=("/left/camera_info", "/right/camera_info"),
        correction=result,
        corrected=None,
    )
    paths, line = write_corrected(run, out, "poster.mcap")
    assert [p.name for p in paths] == ["correction.json"]
    assert line.startswith("no corrected calibration written: degenerate window"), line
    assert "removed the earlier run's left.yaml, right.yaml" in line
    assert sorted(p.name for p in out.iterdir()) == ["correction.json"]
    summary = json.loads((out / "correction.json").read_text())
    assert summary["corrected"] is False and summary["files"] == []
    assert summary["reason"] == result.reason and "correction" not in summary
