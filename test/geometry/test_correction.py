"""Stereo correction: the rotation of a knocked camera b from a window of pairs, and the
camera_info of the corrected rectification."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from sepfm_ros.geometry.calibrated.calibration_check import StereoCalibration
from sepfm_ros.geometry.calibrated.camera import camera_model, undistort_points
from sepfm_ros.geometry.calibrated.correction import (
    CorrectionConfig,
    CorrectionWindow,
    estimate_correction,
)
from sepfm_ros.geometry.calibrated.stereo_rectify import corrected_models

SIZE = (1280, 720)
K_A = np.array([[700.0, 0, 630.0], [0, 705.0, 370.0], [0, 0, 1]])
K_B = np.array([[690.0, 0, 650.0], [0, 695.0, 355.0], [0, 0, 1]])
D = np.array([-0.2, 0.05, 0.001, -0.001, 0.0])
R0 = cv2.Rodrigues(np.radians([0.8, -1.5, 0.6]))[0]
T0 = np.array([-0.12, 0.004, 0.006])


def _models():
    R1, R2, P1, P2 = cv2.stereoRectify(K_A, D, K_B, D, SIZE, R0, T0.reshape(3, 1), alpha=0)[:4]
    return (
        camera_model(K_A, D, "plumb_bob", R1, P1, *SIZE),
        camera_model(K_B, D, "plumb_bob", R2, P2, *SIZE),
    )


def _rig() -> StereoCalibration:
    return StereoCalibration.from_models(*_models())


def _pair(delta_deg, seed: int, n: int = 400, noise: float = 0.3, spread: float = 1.0):
    """Undistorted matches of random points; camera b turned by delta about its own centre."""
    rng = np.random.default_rng(seed)
    X = np.stack(
        [rng.uniform(-6, 6, n) * spread, rng.uniform(-2, 2, n) * spread, rng.uniform(3, 30, n)],
        axis=1,
    )
    return _scene_pair(X, delta_deg, rng, noise)


def _scene_pair(X: np.ndarray, delta_deg, rng: np.random.Generator, noise: float = 0.3):
    """Undistorted matches (N, 2) x 2 of the scene points X (N, 3, metres, camera a's frame)
    seen by the rig with camera b turned by ``delta_deg`` (3,) about its own centre; pixel
    noise of ``noise`` px (std); the points outside either image are dropped."""
    n = len(X)
    dR = cv2.Rodrigues(np.radians(np.asarray(delta_deg, float)).reshape(3, 1))[0]
    xa, _ = cv2.projectPoints(X, np.zeros(3), np.zeros(3), K_A, D)
    xb, _ = cv2.projectPoints(X, cv2.Rodrigues(dR @ R0)[0], dR @ T0, K_B, D)
    xa = xa.reshape(-1, 2) + rng.normal(0, noise, (n, 2))
    xb = xb.reshape(-1, 2) + rng.normal(0, noise, (n, 2))
    inside = np.all((xa > 0) & (xa < SIZE) & (xb > 0) & (xb < SIZE), axis=1)
    calib = _rig()
    return undistort_points(calib.model_a, xa[inside]), undistort_points(calib.model_b, xb[inside])


def _window(delta_deg, pairs: int, seed: int = 0, **kw) -> CorrectionWindow:
    window = CorrectionWindow(40)
    for k in range(pairs):
        window.add(*_pair(delta_deg, seed * 1000 + k, **kw))
    return window


@pytest.mark.parametrize("axis", [0, 2])
def test_knocked_camera_is_corrected(axis):
    delta = np.zeros(3)
    delta[axis] = 0.5
    calib = _rig()
    result = estimate_correction(calib, _window(delta, 20), CorrectionConfig())
    fix = result.correction
    assert fix is not None, result.reason
    assert fix.axes_deg[axis] == pytest.approx(0.5, abs=0.02)
    assert fix.n_pairs == 20 and fix.n_matches > 20 * 200
    # the interval covers the truth on the corrected axis and is narrow
    assert abs(fix.axes_deg[axis] - 0.5) <= fix.interval_deg[axis] + 0.005
    assert fix.interval_deg[axis] < 0.03
    # b turned about its own centre: the rotation and the translation both turn
    dR = cv2.Rodrigues(np.radians(delta).reshape(3, 1))[0]
    err = np.degrees(np.linalg.norm(cv2.Rodrigues(fix.R @ (dR @ calib.R).T)[0]))
    assert err < 0.03 + abs(fix.axes_deg[1])
    assert np.linalg.norm(fix.t) == pytest.approx(np.linalg.norm(calib.t))


def test_too_few_pairs_give_no_correction():
    result = estimate_correction(_rig(), _window([0.5, 0, 0], 3), CorrectionConfig())
    assert result.correction is None
    assert "too few pairs" in result.reason


def test_clean_rig_gets_no_correction():
    result = estimate_correction(_rig(), _window([0, 0, 0], 40), CorrectionConfig())
    assert result.correction is None, result.reason
    assert "no correction needed" in result.reason


def test_bad_pairs_are_dropped():
    calib = _rig()
    window = _window([0.0, 0.0, 0.5], 20)
    rng = np.random.default_rng(7)
    for _ in range(4):  # pairs of wrong matches (a repeated texture, a moving object)
        pa, pb = _pair([0.0, 0.0, 0.5], int(rng.integers(1 << 30)))
        window.add(pa, pb + np.array([0.0, 25.0]))
    fix = estimate_correction(calib, window, CorrectionConfig()).correction
    assert fix is not None
    assert fix.axes_deg[2] == pytest.approx(0.5, abs=0.02)
    assert fix.n_pairs <= 20


def test_matches_in_a_small_patch_give_no_correction():
    result = estimate_correction(_rig(), _window([0.5, 0, 0], 20, spread=0.05), CorrectionConfig())
    assert result.correction is None
    assert "degenerate window: the matches span" in result.reason, result.reason


# Degenerate windows, or not. The fit is a 3-dof rotation of b with the intrinsics and the
# baseline direction known: for matches of a plane (x_b = H x_a, H = K_b (R + t n^T / d)
# K_a^-1) the calibrated E' = [t]x R' explains them only if R^T [t]x R' is antisymmetric,
# which to first order holds for R' = R alone. So a plane that fills the view determines the
# rotation, and so do points at infinity (no parallax: x_b = K_b R K_a^-1 x_a, the rotation
# itself). What does not: matches spanning a small part of the view (a small plane, a plane
# seen edge-on: a line in the image) and matches too few or too poor for the interval.


def _wall(rng: np.random.Generator, n: int, depth: float = 5.0, tilt_deg: float = 0.0):
    """(n, 3) points of a 10 x 5.6 m wall centred 5 m ahead of a, turned by tilt about y."""
    s, v = rng.uniform(-5.0, 5.0, n), rng.uniform(-2.8, 2.8, n)
    a = np.radians(tilt_deg)
    return np.stack([s * np.cos(a), v, depth + s * np.sin(a)], axis=1)


def _ground(rng: np.random.Generator, n: int):
    """(n, 3) points of the ground 1.5 m below a, from 1 to 40 m ahead, within the view."""
    z = rng.uniform(1.0, 40.0, n)
    return np.stack([rng.uniform(-0.75, 0.75, n) * z, np.full(n, 1.5), z], axis=1)


def _infinity(rng: np.random.Generator, n: int):
    """(n, 3) points 10^6 m away over the whole view: no parallax."""
    x, y = rng.uniform(-0.9, 0.9, n), rng.uniform(-0.5, 0.5, n)
    return np.stack([x, y, np.ones(n)], axis=1) * 1e6


def _edge_on(rng: np.random.Generator, n: int):
    """(n, 3) points of the plane y = 0 through both centres (the rig's horizontal plane),
    from 2 to 40 m: seen edge-on, a line in each image."""
    return np.stack([rng.uniform(-8.0, 8.0, n), np.zeros(n), rng.uniform(2.0, 40.0, n)], axis=1)


def _small_wall(rng: np.random.Generator, n: int):
    """(n, 3) points of a 0.8 x 0.6 m poster 5 m ahead: a small part of the view."""
    return np.stack([rng.uniform(-0.4, 0.4, n), rng.uniform(-0.3, 0.3, n), np.full(n, 5.0)], axis=1)


def _scene_window(scene, delta_deg, pairs: int = 20, seed: int = 0) -> CorrectionWindow:
    window = CorrectionWindow(40)
    for k in range(pairs):
        rng = np.random.default_rng(seed * 1000 + k)
        window.add(*_scene_pair(scene(rng, 400), delta_deg, rng))
    return window


SCENES = {
    "wall": _wall,
    "wall_turned_60_deg": lambda rng, n: _wall(rng, n, tilt_deg=60.0),
    "ground": _ground,
    "no_parallax": _infinity,
}


@pytest.mark.parametrize("axis", [0, 2])
@pytest.mark.parametrize("scene", sorted(SCENES))
def test_a_plane_filling_the_view_or_no_parallax_determines_the_rotation(scene, axis):
    """Measured (20 pairs, 0.3 px noise, 0.5 deg): the wall, turned or not, the ground and
    points at infinity all read the knock within 0.003 deg, intervals 0.006-0.023 deg."""
    delta = np.zeros(3)
    delta[axis] = 0.5
    result = estimate_correction(_rig(), _scene_window(SCENES[scene], delta), CorrectionConfig())
    fix = result.correction
    assert fix is not None, result.reason
    other = 2 - axis
    assert abs(fix.axes_deg[axis] - 0.5) <= fix.interval_deg[axis] + 0.005, result.reason
    assert abs(fix.axes_deg[axis] - 0.5) < 0.02, result.reason
    assert abs(fix.axes_deg[other]) <= fix.interval_deg[other] + 0.005, result.reason
    assert fix.interval_deg[axis] < 0.03 and not fix.yaw_determined, result.reason


@pytest.mark.parametrize("scene", ["wall", "no_parallax"])
def test_a_clean_rig_facing_a_plane_or_the_sky_gets_no_correction(scene):
    result = estimate_correction(
        _rig(), _scene_window(SCENES[scene], [0, 0, 0]), CorrectionConfig()
    )
    assert result.correction is None
    assert result.reason.startswith("no correction needed"), result.reason


@pytest.mark.parametrize("scene", [_edge_on, _small_wall], ids=["edge_on", "small_plane"])
def test_a_plane_seen_edge_on_or_small_gives_no_correction(scene):
    """Matches on a line through the image, or in a patch of 8 % of it: degenerate, and the
    reason says how much of the image they span."""
    result = estimate_correction(_rig(), _scene_window(scene, [0.5, 0, 0]), CorrectionConfig())
    assert result.correction is None
    assert "degenerate window: the matches span" in result.reason, result.reason


def test_few_poor_matches_do_not_determine_the_rotation():
    """40 matches of 3 px noise per pair over the whole view (little texture): the interval is
    0.15 deg, wider than 0.1 deg: no correction, and the reason says the rotation is not
    determined."""
    window = CorrectionWindow(40)
    for k in range(12):
        window.add(*_pair([0.5, 0, 0], 500 + k, n=40, noise=3.0))
    result = estimate_correction(_rig(), window, CorrectionConfig())
    assert result.correction is None
    assert "do not determine the rotation" in result.reason, result.reason


def test_corrected_rectification_aligns_rows():
    """Rectified with the corrected camera_info the knocked rig's rows align again."""
    model_a, model_b = _models()
    calib = _rig()
    delta = np.array([0.4, 0.0, -0.6])
    fix = estimate_correction(calib, _window(delta, 20), CorrectionConfig()).correction
    assert fix is not None
    new_a, new_b = corrected_models(model_a, model_b, fix.R, fix.t, rectified=False)
    np.testing.assert_array_equal(new_a.K, model_a.K)
    np.testing.assert_array_equal(new_b.D, model_b.D)
    assert new_b.P[0, 3] == pytest.approx(model_b.P[0, 3], rel=1e-9)
    np.testing.assert_allclose(new_b.P[:, :3], model_b.P[:, :3])
    pa, pb = _pair(delta, 99, noise=0.0)

    def rect(model, pts):
        out = cv2.undistortPoints(pts.reshape(-1, 1, 2), model.K, None, R=model.R, P=model.P)
        return out.reshape(-1, 2)

    stale = np.abs(rect(model_a, pa)[:, 1] - rect(model_b, pb)[:, 1])
    fixed = np.abs(rect(new_a, pa)[:, 1] - rect(new_b, pb)[:, 1])
    assert np.median(stale) > 3.0
    assert np.median(fixed) < 0.1


def test_corrected_models_of_rectified_images():
    """Rectified input: K = old P[:, :3], D = 0; R turns the stale rectified frame."""
    model_a, model_b = _models()
    calib = StereoCalibration.from_models(model_a, model_b, rectified=True)
    dR = cv2.Rodrigues(np.radians([0.3, 0.0, 0.2]).reshape(3, 1))[0]
    new_a, new_b = corrected_models(model_a, model_b, dR @ calib.R, dR @ calib.t, rectified=True)
    np.testing.assert_allclose(new_b.K, model_b.P[:, :3])
    assert not np.any(new_b.D)
    # the two rectified frames end parallel: R_b' (dR) R_a'^T = I
    np.testing.assert_allclose(new_b.R @ dR @ new_a.R.T, np.eye(3), atol=1e-9)


def test_bad_config_is_refused():
    with pytest.raises(ValueError, match="min_pairs"):
        CorrectionConfig(window=5, min_pairs=10)
    with pytest.raises(ValueError, match="differ in length"):
        CorrectionWindow().add(np.zeros((30, 2)), np.zeros((29, 2)))
