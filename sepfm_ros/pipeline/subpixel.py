"""Sub-pixel positions of matched points in image b, for the stereo calibration's correction.

ORB finds keypoints on whole pixels of its pyramid levels, so a match's position is quantised to
up to half a pixel of its level (more than half a pixel of the image at the coarser levels), and
that error depends on the scene's texture: a correction fitted to the matches of consecutive
frames of one scene inherits it, and no number of pairs averages it out. Tracking the patch
around each match's point in image a into image b (pyramidal Lucas-Kanade,
``cv2.calcOpticalFlowPyrLK``, started at the matched point) measures where that patch lies in b to
a few hundredths of a pixel; the point in image a is kept, so the pair is the same point seen in
both images. No ROS.
"""

from __future__ import annotations

import cv2
import numpy as np

from sepfm_ros.pipeline.features import to_gray

#: side of the tracked patch (px)
WINDOW_PX = 15
#: a refined point further than this from the matched one (px) is a failed track
MAX_SHIFT_PX = 2.0
_CRITERIA = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.001)


def refine_points_b(
    image_a: np.ndarray,
    image_b: np.ndarray,
    pts_a: np.ndarray,
    pts_b: np.ndarray,
    window_px: int = WINDOW_PX,
    max_shift_px: float = MAX_SHIFT_PX,
) -> np.ndarray:
    """Where the patch around each point of image a lies in image b, to sub-pixel accuracy.

    Args:
        image_a, image_b: (H, W) or (H, W, 3|4) images (their sizes may differ).
        pts_a, pts_b: (N, 2) matched points, image pixels (x right, y down).
        window_px: side of the tracked patch (px, odd, >= 3).
        max_shift_px: tracks that end further than this from ``pts_b`` (px) fail.

    Returns:
        (N, 2) float64 refined points in image b (px); NaN rows where tracking failed (lost,
        moved too far, or too close to the border).
    """
    a = np.asarray(pts_a, dtype=np.float32).reshape(-1, 1, 2)
    b = np.ascontiguousarray(np.asarray(pts_b, dtype=np.float32).reshape(-1, 1, 2))
    if len(a) != len(b):
        raise ValueError(f"pts_a and pts_b differ in length: {len(a)} and {len(b)}")
    out = np.full((len(a), 2), np.nan)
    if len(a) == 0:
        return out
    grey_a, grey_b = _same_size(to_gray(image_a), to_gray(image_b))
    tracked, status, _ = cv2.calcOpticalFlowPyrLK(
        grey_a,
        grey_b,
        a,
        b.copy(),
        winSize=(int(window_px), int(window_px)),
        maxLevel=1,
        criteria=_CRITERIA,
        flags=cv2.OPTFLOW_USE_INITIAL_FLOW,
    )
    moved = tracked.reshape(-1, 2).astype(np.float64)
    ok = status.reshape(-1).astype(bool) & np.all(np.isfinite(moved), axis=1)
    ok &= np.linalg.norm(moved - b.reshape(-1, 2), axis=1) <= float(max_shift_px)
    out[ok] = moved[ok]
    return out


def _same_size(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The two (H, W) images padded with zeros on the right and bottom to one size (the tracker
    needs it; a rig's two cameras may differ): pixel coordinates are unchanged."""
    h, w = max(a.shape[0], b.shape[0]), max(a.shape[1], b.shape[1])

    def pad(im: np.ndarray) -> np.ndarray:
        if im.shape == (h, w):
            return im
        return np.asarray(
            cv2.copyMakeBorder(im, 0, h - im.shape[0], 0, w - im.shape[1], cv2.BORDER_CONSTANT)
        )

    return pad(a), pad(b)
