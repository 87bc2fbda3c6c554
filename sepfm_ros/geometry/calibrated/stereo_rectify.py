"""The camera_info a driver should load after a correction: a new rectification of corrected
extrinsics, with the input's conventions. No ROS.

:func:`corrected_models` keeps each camera's K and D and recomputes R and P with
``cv2.stereoRectify`` (zero disparity at infinity) from the corrected pose; P keeps the input's
rectified intrinsics (P[:, :3], so the rectified images keep their focal length, principal point
and size) and the input's baseline form ``P_b[:, 3] = P_b[:, :3] @ (offset)``, e.g.
``P_b[0, 3] = -fx' B`` for a horizontal rig, B the calibrated baseline.

Rectified input (``image_rect``): the images are already rectified with the stale calibration.
Their model is then K = P_old[:, :3], D = 0 (:meth:`CameraModel.rectified`), and the returned
camera_info describes these images as *raw* images of that camera: K = P_old[:, :3], D = 0,
R = the rotation from the stale-rectified camera frame to the corrected rectified frame, P as
above. A pipeline that rectifies them again with this camera_info (image_proc's
``initUndistortRectifyMap``) gets images rectified with the corrected calibration.
"""

from __future__ import annotations

import cv2
import numpy as np

from sepfm_ros.geometry.calibrated.camera import CameraModel
from sepfm_ros.geometry.calibrated.pose import rectified_offset


def corrected_models(
    model_a: CameraModel,
    model_b: CameraModel,
    R_corrected: np.ndarray,
    t: np.ndarray,
    rectified: bool,
) -> tuple[CameraModel, CameraModel]:
    """The camera_info models (a, b) a driver should load for the corrected rig.

    Args:
        model_a, model_b: the input camera_info models (as received).
        R_corrected: (3, 3) corrected rotation of b relative to a (``X_b = R X_a + t``) in the
            frames of the images the estimator sees (raw frames; stale-rectified frames for
            rectified input).
        t: (3,) the corrected translation (metres).
        rectified: the input images are rectified (see the module docstring).
    Returns:
        (model_a, model_b): K, D as received (rectified input: P_old[:, :3] and no distortion),
        R and P of the new rectification.
    Raises:
        ValueError: R_corrected is not a rotation or t is zero.
    """
    R = np.asarray(R_corrected, dtype=np.float64).reshape(3, 3)
    tv = np.asarray(t, dtype=np.float64).reshape(3)
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) <= 0:
        raise ValueError("R_corrected is not a rotation matrix")
    if not np.linalg.norm(tv) > 0:
        raise ValueError("t is zero: no stereo baseline")
    src_a = model_a.rectified() if rectified else model_a
    src_b = model_b.rectified() if rectified else model_b
    # the rectifying rotations depend on the pose only (distortion changes stereoRectify's P,
    # which is replaced below)
    R1, R2, _, P2 = cv2.stereoRectify(
        src_a.K,
        np.zeros(5),
        src_b.K,
        np.zeros(5),
        src_a.size,
        R,
        tv.reshape(3, 1),
        flags=cv2.CALIB_ZERO_DISPARITY,
        alpha=-1,
    )[:4]
    # keep the input's rectified intrinsics; the baseline offset along stereoRectify's axis
    P_old_a, P_old_b = model_a.P, model_b.P
    offset_dir = np.asarray(P2[:, 3] / P2[0, 0])  # -B along the rectified baseline axis
    base_old = float(np.linalg.norm(rectified_offset(model_b) - rectified_offset(model_a)))
    base = base_old if base_old > 0 else float(np.linalg.norm(tv))
    offset = offset_dir / max(float(np.linalg.norm(offset_dir)), 1e-12) * base
    Pa = np.c_[P_old_a[:, :3], P_old_a[:, :3] @ rectified_offset(model_a)]
    Pb = np.c_[P_old_b[:, :3], P_old_b[:, :3] @ (rectified_offset(model_a) + offset)]
    return (
        CameraModel(src_a.K.copy(), _out_D(src_a), src_a.distortion_model, R1, Pa, *src_a.size),
        CameraModel(src_b.K.copy(), _out_D(src_b), src_b.distortion_model, R2, Pb, *src_b.size),
    )


def _out_D(model: CameraModel) -> np.ndarray:
    """The D to publish: as received, five zeros when none (plumb_bob)."""
    return model.D.copy() if model.D.size else np.zeros(5)
