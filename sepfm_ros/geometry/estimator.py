"""PROVISIONAL placeholder (being replaced by the separable two-stage estimator)."""

from __future__ import annotations

import cv2
import numpy as np

from sepfm_ros.geometry.epipolar import normalize_fundamental, symmetric_epipolar_distance
from sepfm_ros.geometry.estimate import Estimate

METHODS = ("sep4", "sep5", "sep4-lmeds", "sep5-lmeds", "ransac7", "ransac8", "lmeds7")


def estimate_fundamental(pts1, pts2, image_size1, image_size2=None, method="sep5",
                         threshold=1.0, confidence=0.99, seed=None, **options) -> Estimate:
    pts1 = np.asarray(pts1, dtype=np.float64)
    pts2 = np.asarray(pts2, dtype=np.float64)
    n = pts1.shape[0]
    F, _ = cv2.findFundamentalMat(pts1, pts2, cv2.FM_RANSAC, threshold, confidence)
    if F is None or F.shape != (3, 3):
        return Estimate(F=None, inliers=np.zeros(n, bool), status="no model", method=method)
    F = normalize_fundamental(F)
    inl = symmetric_epipolar_distance(F, pts1, pts2) < threshold
    return Estimate(F=F, inliers=inl, method=method)
