"""Pictures of a pipeline result: both images side by side, inliers, line pair, epipolar lines.

Used by the node's ``~/debug_image`` and by offline tools that save images. OpenCV only, no ROS.
"""

from __future__ import annotations

import cv2
import numpy as np

from sepfm_ros.pipeline.pipeline import PipelineResult

INLIER = (0, 200, 0)
OUTLIER = (0, 0, 220)
LINE_PAIR = (255, 120, 0)
EPIPOLAR = (0, 220, 255)


def _bgr(image: np.ndarray) -> np.ndarray:
    if image.ndim == 2:
        return cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    if image.shape[2] == 4:
        return cv2.cvtColor(image, cv2.COLOR_BGRA2BGR)
    return image.copy()


def _clip_line(line: np.ndarray, width: int, height: int) -> tuple[tuple[int, int], ...] | None:
    """Endpoints of the line a u + b v + c = 0 across a width x height image, or None."""
    a, b, c = (float(x) for x in line)
    pts = []
    if abs(b) > 1e-12:
        for u in (0.0, width - 1.0):
            pts.append((u, -(a * u + c) / b))
    if abs(a) > 1e-12:
        for v in (0.0, height - 1.0):
            pts.append((-(b * v + c) / a, v))
    inside = [(u, v) for u, v in pts if -1 <= u <= width and -1 <= v <= height]
    if len(inside) < 2:
        return None
    (u0, v0), (u1, v1) = inside[0], inside[-1]
    return (round(u0), round(v0)), (round(u1), round(v1))


def draw_result(
    image_a: np.ndarray, image_b: np.ndarray, result: PipelineResult, epipolar_lines: int = 8
) -> np.ndarray:
    """A bgr8 (max(Ha, Hb), Wa + Wb, 3) picture: image a left, image b right.

    Inlier matches are green dots joined by thin lines, outliers red dots; the estimator's line
    pair is drawn in blue; ``epipolar_lines`` epipolar lines of the best inliers in yellow (their
    lines in image b from points of a, and in image a from points of b).
    """
    a, b = _bgr(image_a), _bgr(image_b)
    ha, wa = a.shape[:2]
    hb, wb = b.shape[:2]
    canvas = np.zeros((max(ha, hb), wa + wb, 3), dtype=np.uint8)
    canvas[:ha, :wa] = a
    canvas[:hb, wa:] = b
    m, est = result.matches, result.estimate
    inl = est.inliers if len(est.inliers) == len(m) else np.zeros(len(m), bool)
    for (ua, va), (ub, vb), ok in zip(m.pts_a, m.pts_b, inl, strict=True):
        color = INLIER if ok else OUTLIER
        pa, pb = (round(ua), round(va)), (round(ub) + wa, round(vb))
        cv2.circle(canvas, pa, 2, color, -1)
        cv2.circle(canvas, pb, 2, color, -1)
        if ok:
            cv2.line(canvas, pa, pb, INLIER, 1, cv2.LINE_AA)
    if est.line_pair is not None:
        for line, (w, h, dx) in zip(est.line_pair, ((wa, ha, 0), (wb, hb, wa)), strict=True):
            ends = _clip_line(np.asarray(line), w, h)
            if ends:
                cv2.line(canvas, (ends[0][0] + dx, ends[0][1]), (ends[1][0] + dx, ends[1][1]),
                         LINE_PAIR, 2, cv2.LINE_AA)  # fmt: skip
    if est.F is not None and epipolar_lines > 0:
        idx = np.flatnonzero(inl)[:epipolar_lines]
        F = est.F
        for i in idx:
            xa = np.array([*m.pts_a[i], 1.0])
            xb = np.array([*m.pts_b[i], 1.0])
            for line, (w, h, dx) in ((F @ xa, (wb, hb, wa)), (F.T @ xb, (wa, ha, 0))):
                ends = _clip_line(line, w, h)
                if ends:
                    cv2.line(canvas, (ends[0][0] + dx, ends[0][1]), (ends[1][0] + dx, ends[1][1]),
                             EPIPOLAR, 1, cv2.LINE_AA)  # fmt: skip
    return canvas
