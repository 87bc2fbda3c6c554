"""StreamCalibration's correction: a knocked synthetic rig through the real pipeline gets its
corrected rotation once the check flags it; a clean one never; a new calibration starts afresh."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from sepfm_ros.geometry.calibrated.calibration_check import OK, STALE, MonitorConfig
from sepfm_ros.geometry.calibrated.camera import camera_model
from sepfm_ros.geometry.calibrated.correction import CorrectionConfig
from sepfm_ros.pipeline.calibration import StreamCalibration
from sepfm_ros.pipeline.pipeline import Pipeline, PipelineConfig
from sepfm_ros.synthetic.scene import Camera, render
from sepfm_ros.synthetic.sequences import stereo_sequence, street_scene

FRAMES = 14


@pytest.fixture(scope="module")
def sequence():
    return stereo_sequence(FRAMES, speed_m=0.05, seed=0), street_scene(0)


def _models(frames):
    cam_a, cam_b = frames[0].cameras
    R0 = cam_b.R @ cam_a.R.T
    T0 = cam_b.t - R0 @ cam_a.t
    R1, R2, P1, P2 = cv2.stereoRectify(
        cam_a.K, None, cam_b.K, None, cam_a.size, R0, T0.reshape(3, 1), alpha=0
    )[:4]
    return (
        camera_model(cam_a.K, [], "plumb_bob", R1, P1, *cam_a.size),
        camera_model(cam_b.K, [], "plumb_bob", R2, P2, *cam_b.size),
    )


def _run(sequence, delta_deg):
    frames, scene = sequence
    models = _models(frames)
    dR = cv2.Rodrigues(np.radians(np.asarray(delta_deg, float)).reshape(3, 1))[0]
    stream = StreamCalibration(
        True, False, MonitorConfig(), CorrectionConfig(window=20, min_pairs=6)
    )
    stream.update(*models)
    pipe = Pipeline(PipelineConfig())
    outs = []
    for frame in frames:
        left = frame.images[0]
        cb = frame.cameras[1]
        right = render(scene, Camera(cb.K, dR @ cb.R, dR @ cb.t, cb.size))
        result = pipe.process(left, right, cameras=stream.cameras)
        outs.append(stream.outputs(result, 1.0))
    return stream, models, outs


def test_knocked_rig_is_corrected(sequence):
    stream, models, outs = _run(sequence, [0.5, 0.0, 0.0])
    assert all(o.correction is not None for o in outs)
    first = outs[0]
    assert first.status.level == STALE and first.correction.correction is None
    assert "no correction needed" in first.correction.reason
    fix = outs[-1].correction.correction
    assert fix is not None, outs[-1].correction.reason
    assert fix.axes_deg[0] == pytest.approx(0.5, abs=0.03)
    assert abs(fix.axes_deg[2]) < 0.06
    new_a, new_b = stream.corrected_models()
    np.testing.assert_array_equal(new_a.K, models[0].K)
    assert not np.allclose(new_b.R, models[1].R)
    # a new calibration: the correction and its window start afresh
    stream.update(*new_a_b_swapped(models))
    assert stream.correction is None and len(stream.correction_window) == 0
    assert stream.corrected_models() is None


def new_a_b_swapped(models):
    """Another calibration of the same cameras (the right camera's P shifted by a pixel)."""
    a, b = models
    P = b.P.copy()
    P[0, 2] += 1.0
    return a, camera_model(b.K, b.D, b.distortion_model, b.R, P, b.width, b.height)


def test_clean_rig_gets_no_correction(sequence):
    _, _, outs = _run(sequence, [0.0, 0.0, 0.0])
    assert all(o.status.level in (OK, STALE) for o in outs)
    assert all(o.correction.correction is None for o in outs)
