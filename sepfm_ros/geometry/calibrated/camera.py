"""Pinhole camera models from ROS ``CameraInfo`` fields: validation and point undistortion.

A :class:`CameraModel` holds the fields of ``sensor_msgs/CameraInfo`` as numpy arrays: K (3x3),
D (distortion coefficients), the distortion model, R (3x3 rectifying rotation), P (3x4 projection
of the rectified camera) and the image size. No ROS: the adapter in
``sepfm_ros.ros.msgs.calibration`` fills it from a message.

Two kinds of input images exist and the model of each says which pixels the estimator sees:

- raw images (``image_raw``): matched points are undistorted with K and D into *undistorted
  pixels of K* (:func:`undistort_points`); F is then in those coordinates.
- rectified images (``image_rect``): pixels are already those of P's pinhole camera;
  :meth:`CameraModel.rectified` gives the model of such an image (K = P[:, :3], D = 0, R = I)
  and undistortion is the identity.

Pixel convention: OpenCV keypoints (origin at the centre of the top-left pixel, u right, v down).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

# distortion_model -> accepted numbers of coefficients (ROS image_geometry conventions).
DISTORTION_MODELS: dict[str, tuple[int, ...]] = {
    "plumb_bob": (4, 5, 8),
    "rational_polynomial": (8, 12, 14),
    "equidistant": (4,),
}


# Iterative undistortion: OpenCV's default 5 iterations leave up to 0.02 px on strong
# distortion; 50 iterations reach 1e-6 px.
_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-10)


class CalibrationError(ValueError):
    """A camera calibration that cannot be used, with the reason in the message."""


@dataclass(frozen=True)
class CameraModel:
    """A validated camera calibration (build it with :func:`camera_model`).

    Attributes:
        K: (3, 3) float64 intrinsics of the raw image (px).
        D: (n,) float64 distortion coefficients (n = 0 means none).
        distortion_model: "plumb_bob", "rational_polynomial" or "equidistant".
        R: (3, 3) float64 rectifying rotation (raw camera frame -> rectified frame).
        P: (3, 4) float64 projection of the rectified camera (rectified pixels); its last column
            holds the stereo offset (P[0, 3] = -fx' * baseline for a right camera).
        width, height: image size (px).
    """

    K: np.ndarray
    D: np.ndarray
    distortion_model: str
    R: np.ndarray
    P: np.ndarray
    width: int
    height: int

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) in pixels."""
        return (self.width, self.height)

    @property
    def has_distortion(self) -> bool:
        """True when any distortion coefficient is non-zero."""
        return bool(np.any(self.D != 0.0))

    def rectified(self) -> CameraModel:
        """The model of this camera's rectified image (``image_rect``): K = P[:, :3], D = 0, R = I.

        Raises CalibrationError when P has no usable pinhole part (zero focal length).
        """
        K = self.P[:, :3].copy()
        _check_intrinsics(K, "P")
        return CameraModel(K, np.zeros(0), "plumb_bob", np.eye(3), self.P.copy(), *self.size)


def _array(value: object, shape: tuple[int, ...] | None, name: str) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise CalibrationError(f"{name} is not numeric") from None
    if shape is not None:
        if arr.size != int(np.prod(shape)):
            raise CalibrationError(f"{name} has {arr.size} values; expected {int(np.prod(shape))}")
        arr = arr.reshape(shape)
    if not np.all(np.isfinite(arr)):
        raise CalibrationError(f"{name} has NaN or infinite values")
    return arr


def _check_intrinsics(K: np.ndarray, name: str) -> None:
    if not np.any(K):
        raise CalibrationError(f"{name} is all zeros (camera not calibrated)")
    if not (K[0, 0] > 0 and K[1, 1] > 0):
        raise CalibrationError(
            f"{name} has non-positive focal lengths fx={K[0, 0]:g}, fy={K[1, 1]:g}"
        )
    if abs(K[2, 2]) < 1e-12 or np.any(np.abs(K[2, :2]) > 1e-6 * abs(K[2, 2])):
        raise CalibrationError(f"{name} has a last row {K[2].tolist()}; expected [0, 0, 1]")


def camera_model(
    K: object,
    D: object,
    distortion_model: str,
    R: object,
    P: object,
    width: int,
    height: int,
    image_size: tuple[int, int] | None = None,
) -> CameraModel:
    """Validate ``CameraInfo`` fields and build a :class:`CameraModel`.

    Args:
        K: 9 values (row-major 3x3), D: distortion coefficients (may be empty), distortion_model:
            one of ``DISTORTION_MODELS`` (empty string with empty D means none), R: 9 values
            (all zeros = identity, as ROS monocular cameras often send), P: 12 values (all zeros
            = K with a zero last column), width/height: calibrated image size (px).
        image_size: (width, height) of the images actually received, when known; must equal
            the calibrated size.
    Raises:
        CalibrationError: zero K, NaN, wrong sizes, unknown distortion model, image size mismatch.
    """
    K = _array(K, (3, 3), "K")
    _check_intrinsics(K, "K")
    K = K / float(K[2, 2])
    D = _array(D, None, "D").reshape(-1)
    model = str(distortion_model or "")
    if model == "" and not np.any(D):
        model, D = "plumb_bob", np.zeros(0)
    if model not in DISTORTION_MODELS:
        raise CalibrationError(
            f"distortion model {model!r} is not supported; expected one of "
            f"{sorted(DISTORTION_MODELS)}"
        )
    if D.size and D.size not in DISTORTION_MODELS[model]:
        raise CalibrationError(
            f"{model} needs {' or '.join(map(str, DISTORTION_MODELS[model]))} coefficients; "
            f"D has {D.size}"
        )
    R = _array(R, (3, 3), "R")
    if not np.any(R):
        R = np.eye(3)
    elif not np.allclose(R @ R.T, np.eye(3), atol=1e-4) or np.linalg.det(R) < 0:
        raise CalibrationError("R is not a rotation matrix")
    P = _array(P, (3, 4), "P")
    if not np.any(P):
        P = np.concatenate([K, np.zeros((3, 1))], axis=1)
    else:
        _check_intrinsics(P[:, :3], "P")
    try:
        w, h = int(width), int(height)
    except (TypeError, ValueError):
        raise CalibrationError(f"image size {width!r}x{height!r} is not an integer") from None
    if w <= 0 or h <= 0:
        raise CalibrationError(f"calibrated image size {w}x{h} is not positive")
    if image_size is not None and (int(image_size[0]), int(image_size[1])) != (w, h):
        raise CalibrationError(
            f"calibration is for {w}x{h} images but the images are "
            f"{int(image_size[0])}x{int(image_size[1])}"
        )
    return CameraModel(K, D, model, R, P, w, h)


def undistort_points(model: CameraModel, pts: np.ndarray) -> np.ndarray:
    """Undistorted pixels of K of raw-image points (the identity when D is zero).

    Args:
        model: the camera of the image the points are in.
        pts: (N, 2) float pixel coordinates in that image.
    Returns:
        (N, 2) float64 pixel coordinates of an ideal pinhole camera with the same K.
    """
    pts = np.asarray(pts, dtype=np.float64).reshape(-1, 2)
    if not model.has_distortion or len(pts) == 0:
        return pts.copy()
    src = pts.reshape(-1, 1, 2)
    if model.distortion_model == "equidistant":
        out = cv2.fisheye.undistortPoints(src, model.K, model.D, P=model.K, criteria=_CRITERIA)
    else:
        out = cv2.undistortPoints(src, model.K, model.D, R=None, P=model.K, criteria=_CRITERIA)
    return out.reshape(-1, 2).astype(np.float64)


def distort_points(model: CameraModel, pts: np.ndarray) -> np.ndarray:
    """The inverse of :func:`undistort_points`: raw-image pixels of undistorted pixels of K.

    Args:
        pts: (N, 2) undistorted pixel coordinates of K.
    Returns:
        (N, 2) float64 pixel coordinates in the raw (distorted) image.
    """
    pts = np.asarray(pts, dtype=np.float64).reshape(-1, 2)
    if not model.has_distortion or len(pts) == 0:
        return pts.copy()
    rays = np.concatenate([pts, np.ones((len(pts), 1))], axis=1) @ np.linalg.inv(model.K).T
    obj = rays.reshape(-1, 1, 3)
    zero = np.zeros(3)
    if model.distortion_model == "equidistant":
        out, _ = cv2.fisheye.projectPoints(obj, zero, zero, model.K, model.D)
    else:
        out, _ = cv2.projectPoints(obj, zero, zero, model.K, model.D)
    return out.reshape(-1, 2).astype(np.float64)
