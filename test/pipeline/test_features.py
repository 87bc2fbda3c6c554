"""Every detector the package offers (ORB, SIFT, AKAZE) gives matches that recover the GT F."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from ground_truth import gt_fundamental, median_gt_inlier_error
from optional_tools import detector_param

from sepfm_ros.geometry import estimate_fundamental
from sepfm_ros.pipeline import features as features_module
from sepfm_ros.pipeline.features import (
    FEATURES,
    available_features,
    make_detector,
    match_images,
    unavailable_reason,
)
from sepfm_ros.pipeline.pipeline import PipelineConfig


@pytest.mark.parametrize("features", [detector_param(f) for f in FEATURES])
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


def test_orb_and_sift_are_always_offered_akaze_when_cv2_has_it():
    has_akaze = hasattr(cv2, "AKAZE_create") or hasattr(
        getattr(cv2, "xfeatures2d", None), "AKAZE_create"
    )
    assert available_features() == (("orb", "sift", "akaze") if has_akaze else ("orb", "sift"))
    assert (unavailable_reason("akaze") is None) == has_akaze


@pytest.fixture
def cv2_without_akaze(monkeypatch):
    """This environment's cv2 as OpenCV 5's main wheel has it: no AKAZE anywhere (a no-op where
    cv2 really lacks it)."""
    monkeypatch.delattr(cv2, "AKAZE_create", raising=False)
    monkeypatch.delattr(cv2, "xfeatures2d", raising=False)
    features_module.unavailable_reason.cache_clear()
    yield
    features_module.unavailable_reason.cache_clear()


def test_akaze_without_it_is_a_clear_error_naming_the_fix(cv2_without_akaze):
    assert available_features() == ("orb", "sift")
    for error in (
        lambda: make_detector("akaze"),
        lambda: PipelineConfig(features="akaze"),
    ):
        with pytest.raises(ValueError) as e:
            error()
        message = str(e.value)
        assert "features 'akaze' need AKAZE" in message, message
        assert cv2.__version__ in message
        assert "pip install opencv-contrib-python-headless" in message
        assert "pip uninstall -y" in message and "opencv" in message.split("pip uninstall -y")[1]
    assert make_detector("orb") is not None  # the others stay usable
