"""Ground-truth helpers shared by the pipeline and node tests (real images of ../shared/data)."""

from __future__ import annotations

import json
from functools import cache
from pathlib import Path

import numpy as np

from sepfm_ros.geometry import fundamental_from_cameras, symmetric_epipolar_distance

GT_INLIER_PX = 1.0  # a match is a GT inlier when its symmetric epipolar distance under GT F < 1 px


@cache
def _cameras(data: Path) -> dict:
    return json.loads((data / "cameras.json").read_text())


def gt_fundamental(data: Path, img_a: str, img_b: str) -> np.ndarray:
    """GT F (x_b^T F x_a = 0) from cameras.json, for images given relative to ``data``."""
    cams = _cameras(data)
    return fundamental_from_cameras(np.asarray(cams[img_a]), np.asarray(cams[img_b]))


def median_gt_inlier_error(
    F: np.ndarray, F_gt: np.ndarray, pts_a: np.ndarray, pts_b: np.ndarray
) -> tuple[float, int]:
    """(median symmetric epipolar error under F of the GT-inlier matches, their count)."""
    gt_inliers = symmetric_epipolar_distance(F_gt, pts_a, pts_b) < GT_INLIER_PX
    n = int(np.count_nonzero(gt_inliers))
    if n == 0:
        return float("inf"), 0
    errors = symmetric_epipolar_distance(F, pts_a[gt_inliers], pts_b[gt_inliers])
    return float(np.median(errors)), n
