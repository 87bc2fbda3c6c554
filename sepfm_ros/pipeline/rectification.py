"""Uncalibrated stereo rectification: F and its inlier matches -> two rectifying homographies.

No ROS. The homographies are OpenCV's ``stereoRectifyUncalibrated`` (Hartley's method: H_b sends
image b's epipole to infinity along x with the least distortion at the image centre, H_a is the
homography compatible with F that minimises the horizontal disparity of the matches). This
module adds what a live consumer needs around it:

- checks with a clear :class:`RectificationError` (``kind`` one of ``ERROR_KINDS``) instead of
  wild homographies: too few inliers, a degenerate F (rank below 2, non-finite), an epipole
  inside an image (no rectification keeps such an image in one piece), homographies that fold
  an image over the line at infinity, a framed image that covers less than ``min_coverage`` of
  the output or keeps less of itself in it, OpenCV's own failure, and (when asked) a median
  vertical disparity of the matches above ``max_vertical_px`` after rectification;
- (the orientation needs nothing: OpenCV turns image b by at most 90 degrees to put the
  epipole on the x axis, so a side-by-side rig stays upright whichever side camera b is on,
  and a rig stacked vertically comes out turned by 90 degrees, rows along its baseline);
- the framing: one similarity for both images (same scale, same offset, so corresponding rows
  stay equal) that keeps image a's centre at its native pixel scale and centres the region both
  images cover (the bounding boxes' common rows and columns) in an output of a fixed size (image
  a's size unless asked otherwise). Vertical disparities are therefore in native pixels.

Pixels follow the project's convention: x_b^T F x_a = 0, (u, v) with the origin at the centre
of the top-left pixel, u right, v down.

    rect = rectify_uncalibrated(F, pts_a[inliers], pts_b[inliers], (w_a, h_a), (w_b, h_b))
    left_rect, right_rect = rect.warp(left, right)
    np.median(vertical_disparity(rect.H_a, rect.H_b, pts_a, pts_b))   # px, rectified
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

ERROR_KINDS = (
    "bad_input",
    "too_few_inliers",
    "degenerate_f",
    "epipole_inside",
    "distorted",
    "opencv_failed",
    "vertical_disparity",
)
# The fewest inlier matches accepted: H_a's fit has 3 unknowns, and a handful of matches would
# let one wrong match tilt the rows.
MIN_INLIERS = 15
# The least share of the output each framed rectified image must cover, and of each image the
# output must keep: below it the pair has little in common left to match (an epipole just
# outside an image stretches its far side out of any output at the centre's scale).
MIN_COVERAGE = 0.3
# Singular-value ratio s2/s1 of F below which F counts as rank 1 (no epipolar geometry).
RANK_TOL = 1e-9


class RectificationError(ValueError):
    """F and the matches give no usable rectification. ``kind`` is one of ``ERROR_KINDS``."""

    def __init__(self, kind: str, message: str) -> None:
        super().__init__(message)
        self.kind = kind


@dataclass(frozen=True)
class Rectification:
    """Two rectifying homographies and the size of the images they map into.

    Attributes:
        H_a, H_b: (3, 3) float64, pixels of image a (b) -> pixels of rectified image a (b);
            after them corresponding points have equal v.
        size: (width, height) of both rectified images, px.
        size_a, size_b: (width, height) of the input images the homographies are for.
        inliers: number of matches the homographies were fitted and checked on.
    """

    H_a: np.ndarray
    H_b: np.ndarray
    size: tuple[int, int]
    size_a: tuple[int, int]
    size_b: tuple[int, int]
    inliers: int

    def warp(
        self, image_a: np.ndarray, image_b: np.ndarray, interpolation: int = cv2.INTER_LINEAR
    ) -> tuple[np.ndarray, np.ndarray]:
        """Rectify an image pair: (H, W[, C]) arrays of sizes ``size_a`` and ``size_b`` ->
        two arrays of ``size`` (same dtype and channels), black outside the inputs.

        Raises:
            ValueError: an image's size is not the one the homographies are for.
        """
        for name, image, size in (("a", image_a, self.size_a), ("b", image_b, self.size_b)):
            got = (int(image.shape[1]), int(image.shape[0])) if image.ndim >= 2 else None
            if got != tuple(size):
                raise ValueError(f"image {name} is {got} (w, h); the rectification is for {size}")
        return (
            cv2.warpPerspective(image_a, self.H_a, self.size, flags=interpolation),
            cv2.warpPerspective(image_b, self.H_b, self.size, flags=interpolation),
        )


def apply_homography(H: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """(N, 2) pixels -> (N, 2) pixels mapped by the (3, 3) homography H."""
    x = np.asarray(pts, dtype=np.float64) @ H[:, :2].T + H[:, 2]
    return x[:, :2] / x[:, 2:3]


def vertical_disparity(
    H_a: np.ndarray, H_b: np.ndarray, pts_a: np.ndarray, pts_b: np.ndarray
) -> np.ndarray:
    """(N,) |v_a - v_b| (px) of matches (N, 2) + (N, 2) after H_a and H_b (identities: before
    rectification)."""
    return np.abs(apply_homography(H_a, pts_a)[:, 1] - apply_homography(H_b, pts_b)[:, 1])


def epipoles(F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The epipoles of F (3, 3): (e_a, e_b), homogeneous (3,) unit vectors with F e_a = 0 and
    F^T e_b = 0 (e_a is camera b's centre seen in image a)."""
    _, _, vt = np.linalg.svd(F)
    _, _, vt_t = np.linalg.svd(F.T)
    return vt[2], vt_t[2]


def _check_inputs(
    F: np.ndarray, pts_a: np.ndarray, pts_b: np.ndarray, min_inliers: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Validated float64 copies: F (3, 3) forced to rank 2, pts (N, 2) each."""
    F = np.asarray(F, dtype=np.float64)
    pts_a = np.ascontiguousarray(pts_a, dtype=np.float64)  # OpenCV reads rows as stored
    pts_b = np.ascontiguousarray(pts_b, dtype=np.float64)
    if F.shape != (3, 3):
        raise RectificationError("bad_input", f"F must be 3x3, got shape {F.shape}")
    if pts_a.ndim != 2 or pts_a.shape[1:] != (2,) or pts_a.shape != pts_b.shape:
        raise RectificationError(
            "bad_input", f"matches must be two (N, 2) arrays, got {pts_a.shape} and {pts_b.shape}"
        )
    if not (np.isfinite(pts_a).all() and np.isfinite(pts_b).all()):
        raise RectificationError("bad_input", "matches hold NaN or inf")
    if len(pts_a) < min_inliers:
        raise RectificationError(
            "too_few_inliers", f"{len(pts_a)} inlier matches; rectification needs {min_inliers}"
        )
    if not np.isfinite(F).all():
        raise RectificationError("degenerate_f", "F holds NaN or inf")
    u, s, vt = np.linalg.svd(F)
    if s[0] <= 0 or s[1] / s[0] < RANK_TOL:
        raise RectificationError("degenerate_f", f"F has rank below 2 (singular values {s})")
    return u @ np.diag([s[0], s[1], 0.0]) @ vt / s[0], pts_a, pts_b


def _check_epipole(e: np.ndarray, size: tuple[int, int], name: str) -> None:
    """Refuse an epipole (3,) inside image ``name`` of ``size`` (w, h) pixels."""
    w, h = size
    if abs(e[2]) < 1e-12:
        return  # at infinity: the image is rectified by a rotation alone
    u, v = e[0] / e[2], e[1] / e[2]
    if -0.5 <= u <= w - 0.5 and -0.5 <= v <= h - 0.5:
        raise RectificationError(
            "epipole_inside",
            f"the epipole of image {name} lies inside it at ({u:.0f}, {v:.0f}) px (motion toward"
            " the scene, not a side-by-side rig): no rectification keeps the image in one piece",
        )


def _corners(size: tuple[int, int]) -> np.ndarray:
    """(5, 2) the corners and the centre of an image of ``size`` (w, h), px."""
    w, h = size
    return np.array(
        [[-0.5, -0.5], [w - 0.5, -0.5], [w - 0.5, h - 0.5], [-0.5, h - 0.5], [w / 2, h / 2]]
    )


def _jacobian(H: np.ndarray, p: np.ndarray) -> np.ndarray:
    """(2, 2) derivative of the homography H at pixel p (2,)."""
    x = H @ np.array([p[0], p[1], 1.0])
    return (H[:2, :2] * x[2] - np.outer(x[:2], H[2, :2])) / x[2] ** 2


def _check_fold(H: np.ndarray, size: tuple[int, int], name: str) -> None:
    """Refuse an H that folds image ``name`` of ``size`` (w, h) over the line at infinity."""
    w = _corners(size) @ H[2, :2] + H[2, 2]
    if not (np.all(w > 0) or np.all(w < 0)):
        raise RectificationError(
            "distorted",
            f"the rectification of image {name} crosses the line at infinity (the epipole is"
            " too close to the image)",
        )


def _frame(
    H_a: np.ndarray,
    H_b: np.ndarray,
    size_a: tuple[int, int],
    size_b: tuple[int, int],
    out_size: tuple[int, int],
) -> np.ndarray:
    """(3, 3) the similarity S for both images (see the module docstring): native scale at
    image a's centre, the rows and columns both images cover centred in ``out_size`` (w, h)
    px."""
    scale = 1.0 / np.sqrt(abs(np.linalg.det(_jacobian(H_a, _corners(size_a)[4]))))
    boxes = []
    for H, size in ((H_a, size_a), (H_b, size_b)):
        p = apply_homography(H, _corners(size)[:4]) * scale
        boxes.append((p[:, 0].min(), p[:, 0].max(), p[:, 1].min(), p[:, 1].max()))
    x0, x1 = max(b[0] for b in boxes), min(b[1] for b in boxes)
    y0, y1 = max(b[2] for b in boxes), min(b[3] for b in boxes)
    if y1 <= y0 or x1 <= x0:
        raise RectificationError("distorted", "the rectified images share no rows or columns")
    tx = (out_size[0] - 1) / 2 - (x0 + x1) / 2
    ty = (out_size[1] - 1) / 2 - (y0 + y1) / 2
    return np.array([[scale, 0.0, tx], [0.0, scale, ty], [0.0, 0.0, 1.0]])


def coverage(
    H: np.ndarray, size: tuple[int, int], out_size: tuple[int, int]
) -> tuple[float, float]:
    """How an image of ``size`` (w, h) and an output of ``out_size`` (w, h) overlap after the
    homography H (which must not fold the image: :func:`_check_fold`): (the share of the output
    the image covers, the share of the image inside the output), each 0..1; the second is
    counted on a grid of 32 x 32 pixels."""
    quad = apply_homography(H, _corners(size)[:4]).astype(np.float32)
    w, h = out_size
    box = np.array([[-0.5, -0.5], [w - 0.5, -0.5], [w - 0.5, h - 0.5], [-0.5, h - 0.5]])
    if cv2.contourArea(quad, oriented=True) < 0:
        quad = quad[::-1].copy()
    area, _ = cv2.intersectConvexConvex(quad, box.astype(np.float32))
    u, v = np.meshgrid(np.linspace(0, size[0] - 1, 32), np.linspace(0, size[1] - 1, 32))
    p = apply_homography(H, np.c_[u.ravel(), v.ravel()])
    inside = (p[:, 0] >= -0.5) & (p[:, 0] < w - 0.5) & (p[:, 1] >= -0.5) & (p[:, 1] < h - 0.5)
    return float(area) / (w * h), float(inside.mean())


def rectify_uncalibrated(
    F: np.ndarray,
    pts_a: np.ndarray,
    pts_b: np.ndarray,
    size_a: tuple[int, int],
    size_b: tuple[int, int],
    out_size: tuple[int, int] | None = None,
    min_inliers: int = MIN_INLIERS,
    min_coverage: float = MIN_COVERAGE,
    max_vertical_px: float | None = None,
) -> Rectification:
    """Rectifying homographies of an uncalibrated stereo pair.

    Args:
        F: (3, 3) with x_b^T F x_a = 0 in pixels (any scale; forced to rank 2).
        pts_a, pts_b: (N, 2) pixels of F's inlier matches in image a and image b.
        size_a, size_b: (width, height) of the two images, px.
        out_size: (width, height) of the rectified images; default ``size_a``.
        min_inliers: fewest matches accepted.
        min_coverage: least share of the output each framed image covers, and of each image
            the output keeps (0..1).
        max_vertical_px: when given, the largest median |v_a - v_b| of the matches after
            rectification, px.
    Returns:
        A :class:`Rectification`.
    Raises:
        RectificationError: see the module docstring; ``kind`` names the reason.
    """
    F, pts_a, pts_b = _check_inputs(F, pts_a, pts_b, min_inliers)
    size_a = (int(size_a[0]), int(size_a[1]))
    size_b = (int(size_b[0]), int(size_b[1]))
    out_size = size_a if out_size is None else (int(out_size[0]), int(out_size[1]))
    if min(*size_a, *size_b, *out_size) <= 0:
        raise RectificationError("bad_input", f"image sizes must be positive: {size_a}, {size_b}")
    e_a, e_b = epipoles(F)
    _check_epipole(e_a, size_a, "a")
    _check_epipole(e_b, size_b, "b")
    # OpenCV centres image b (its imgSize) before sending the epipole to infinity
    try:
        ok, H_a, H_b = cv2.stereoRectifyUncalibrated(pts_a, pts_b, F, size_b, threshold=0)
    except cv2.error as err:
        raise RectificationError("opencv_failed", f"stereoRectifyUncalibrated: {err}") from None
    if not ok or H_a is None or not (np.isfinite(H_a).all() and np.isfinite(H_b).all()):
        raise RectificationError("opencv_failed", "OpenCV's stereoRectifyUncalibrated failed")
    for H, size, name in ((H_a, size_a, "a"), (H_b, size_b, "b")):
        _check_fold(H, size, name)
    S = _frame(H_a, H_b, size_a, size_b, out_size)
    H_a, H_b = S @ H_a, S @ H_b
    for H, size, name in ((H_a, size_a, "a"), (H_b, size_b, "b")):
        covered, kept = coverage(H, size, out_size)
        if min(covered, kept) < min_coverage:
            raise RectificationError(
                "distorted",
                f"rectified image {name} covers {100 * covered:.0f} % of the output and keeps"
                f" {100 * kept:.0f} % of itself in it (at least {100 * min_coverage:.0f} % each):"
                " the epipole is too close to the image, or the views share too little",
            )
    if max_vertical_px is not None:
        vd = float(np.median(vertical_disparity(H_a, H_b, pts_a, pts_b)))
        if not vd <= max_vertical_px:
            raise RectificationError(
                "vertical_disparity",
                f"the matches keep a median vertical disparity of {vd:.2f} px after"
                f" rectification (at most {max_vertical_px:g} px)",
            )
    return Rectification(
        H_a=H_a / H_a[2, 2] if abs(H_a[2, 2]) > 1e-12 else H_a,
        H_b=H_b / H_b[2, 2] if abs(H_b[2, 2]) > 1e-12 else H_b,
        size=out_size,
        size_a=size_a,
        size_b=size_b,
        inliers=len(pts_a),
    )
