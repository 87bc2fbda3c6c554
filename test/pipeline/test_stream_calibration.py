"""StreamCalibration (pipeline/calibration.py): a stream's camera models, the stereo rig, and
when the calibration check's window starts afresh."""

from __future__ import annotations

import numpy as np

from sepfm_ros.geometry.calibrated.camera import camera_model
from sepfm_ros.pipeline.calibration import StreamCalibration

K = np.array([[700.0, 0.0, 320.0], [0.0, 700.0, 240.0], [0.0, 0.0, 1.0]])


def rig(fx_noise: float = 0.0, baseline: float = 0.12):
    k = K.copy()
    k[0, 0] += fx_noise
    P_l = np.hstack([k, np.zeros((3, 1))])
    P_r = P_l.copy()
    P_r[0, 3] = -k[0, 0] * baseline
    return [
        camera_model(k.ravel(), np.zeros(5), "plumb_bob", np.eye(3).ravel(), P.ravel(), 640, 480)
        for P in (P_l, P_r)
    ]


def test_a_rig_with_a_baseline_gets_a_calibration_check():
    calib = StreamCalibration(stereo=True, rectified=False)
    assert calib.update(*rig())
    assert calib.rig is not None and calib.rig_problem is None
    assert abs(calib.rig.baseline - 0.12) < 1e-12
    assert calib.cameras is not None


def test_camera_info_equal_to_rounding_keeps_the_window():
    calib = StreamCalibration(stereo=True, rectified=False)
    assert calib.update(*rig())
    # the same calibration recomputed per message (last digits differ): not a change
    assert not calib.update(*rig(fx_noise=1e-10))
    # ... or recomputed in single precision by the driver
    single = [
        camera_model(
            *(np.float32(getattr(m, f)).astype(np.float64).ravel() for f in ("K", "D")),
            "plumb_bob",
            *(np.float32(getattr(m, f)).astype(np.float64).ravel() for f in ("R", "P")),
            640,
            480,
        )
        for m in rig(fx_noise=1.0 / 3.0)
    ]
    assert calib.update(*rig(fx_noise=1.0 / 3.0))
    assert not calib.update(*single)
    # a real change (another focal length, a hundredth of a pixel): the check starts afresh
    assert calib.update(*rig(fx_noise=0.01))
    assert calib.update(*rig(fx_noise=0.5))


def test_motion_has_no_rig_and_rectified_uses_p():
    calib = StreamCalibration(stereo=False, rectified=True)
    model = rig()[0]
    calib.update(model, model)
    assert calib.rig is None
    np.testing.assert_array_equal(calib.cameras[0].K, model.P[:, :3])
    assert not calib.cameras[0].has_distortion
