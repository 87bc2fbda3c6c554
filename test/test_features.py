"""Every detector the package offers (ORB, SIFT, AKAZE) gives matches that recover the GT F."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from ground_truth import gt_fundamental, median_gt_inlier_error

from sepfm_ros.geometry import estimate_fundamental
from sepfm_ros.pipeline.features import FEATURES, make_detector, match_images


@pytest.mark.parametrize("features", FEATURES)
def test_detector_matches_recover_gt_F(features, shared_data):
    a, b = "templeRing/templeR0001.png", "templeRing/templeR0002.png"
    img_a = cv2.imread(str(shared_data / a), cv2.IMREAD_GRAYSCALE)
    img_b = cv2.imread(str(shared_data / b), cv2.IMREAD_GRAYSCALE)
    m = match_images(img_a, img_b, features, 1000, 0.8)
    assert len(m) >= 50
    assert np.all(np.diff(m.ratio) >= 0)  # best first
    est = estimate_fundamental(m.pts_a, m.pts_b, (640, 480), seed=0)
    err, n = median_gt_inlier_error(est.F, gt_fundamental(shared_data, a, b), m.pts_a, m.pts_b)
    assert n >= 20 and err < 1.0, (features, err, n)


def test_unknown_detector_is_a_value_error():
    with pytest.raises(ValueError, match="unknown features"):
        make_detector("surf")
