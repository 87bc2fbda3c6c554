"""Pipeline: images -> matches -> F on real pairs with GT, determinism, caching, bad config."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from ground_truth import gt_fundamental, median_gt_inlier_error
from optional_tools import detector_param

from sepfm_ros.pipeline.drawing import draw_result
from sepfm_ros.pipeline.pipeline import MIN_MATCHES, Pipeline, PipelineConfig

PAIRS = {
    "kitti_stereo": ("kitti_seq2/left/000000.png", "kitti_seq2/right/000000.png"),
    "kitti_motion": ("kitti_seq2/left/000010.png", "kitti_seq2/left/000011.png"),
    "temple_motion": ("templeRing/templeR0001.png", "templeRing/templeR0002.png"),
}


def load(data, rel):
    image = cv2.imread(str(data / rel), cv2.IMREAD_GRAYSCALE)
    assert image is not None, rel
    return image


@pytest.mark.parametrize("features", ["orb", "sift"])
@pytest.mark.parametrize("name", sorted(PAIRS))
def test_real_pairs_meet_the_accuracy_criterion(shared_data, name, features):
    img_a, img_b = PAIRS[name]
    result = Pipeline(PipelineConfig(features=features, seed=3)).process(
        load(shared_data, img_a), load(shared_data, img_b)
    )
    assert result.ok, result.estimate.status
    m = result.matches
    assert len(m) >= 50
    assert np.all(np.diff(m.ratio) >= 0), "matches must be sorted best first"
    err, n_gt = median_gt_inlier_error(
        result.estimate.F, gt_fundamental(shared_data, img_a, img_b), m.pts_a, m.pts_b
    )
    assert n_gt >= 30
    assert err < 1.0, f"{name}/{features}: median error of {n_gt} GT inliers {err:.3f} px"
    assert np.isclose(np.linalg.norm(result.estimate.F), 1.0)
    assert result.errors.shape == (len(m),) and np.all(np.isfinite(result.errors))
    assert result.estimate.inliers.shape == (len(m),)
    t = result.timings_ms
    assert all(t[stage] > 0.0 for stage in ("features", "match", "estimate")), t
    assert t["total"] >= t["features"] + t["match"] + t["estimate"], t  # stages are disjoint
    assert (
        result.size_a
        == result.size_b
        == (load(shared_data, img_a).shape[1],) + (load(shared_data, img_a).shape[0],)
    )


def test_same_seed_same_result_and_cache_changes_nothing(shared_data):
    a, b = (load(shared_data, p) for p in PAIRS["temple_motion"])
    config = PipelineConfig(seed=11)
    first = Pipeline(config).process(a, b)
    cached_pipeline = Pipeline(config)
    cached_pipeline.process(a, b, key_a="a", key_b="b")
    second = cached_pipeline.process(a, b, key_a="a", key_b="b")  # features from the cache
    np.testing.assert_array_equal(first.estimate.F, second.estimate.F)
    np.testing.assert_array_equal(first.estimate.inliers, second.estimate.inliers)
    np.testing.assert_array_equal(first.matches.pts_a, second.matches.pts_a)


def test_prior_timings_are_reported_and_counted(shared_data):
    a, b = (load(shared_data, p) for p in PAIRS["temple_motion"])
    result = Pipeline().process(a, b, prior_timings_ms={"decode": 5.0})
    assert list(result.timings_ms)[0] == "decode" and result.timings_ms["decode"] == 5.0
    assert result.timings_ms["total"] >= 5.0 + result.timings_ms["features"]


def test_reconfigure_and_max_matches(shared_data):
    a, b = (load(shared_data, p) for p in PAIRS["kitti_stereo"])
    pipeline = Pipeline()
    pipeline.process(a, b, key_a=1, key_b=2)
    config = pipeline.update(max_matches=40, features="sift")
    assert pipeline.config == config and config.features == "sift"
    result = pipeline.process(a, b, key_a=1, key_b=2)  # cache was dropped with the detector
    assert len(result.matches) == 40


def test_textureless_images_fail_with_a_reason_not_an_exception():
    blank = np.full((120, 160), 128, np.uint8)
    result = Pipeline().process(blank, blank)
    assert not result.ok and result.estimate.F is None
    assert f"< {MIN_MATCHES}" in result.estimate.status
    assert np.all(np.isnan(result.errors))


@pytest.mark.parametrize(
    ("change", "text"),
    [
        ({"features": "surf"}, "features"),
        ({"method": "magic"}, "method"),
        ({"max_features": 3}, "max_features"),
        ({"ratio": 0.0}, "ratio"),
        ({"threshold_px": -1.0}, "threshold_px"),
        ({"confidence": 1.0}, "confidence"),
        ({"seed": -2}, "seed"),
    ],
)
def test_bad_config_is_rejected_with_the_reason(change, text):
    with pytest.raises(ValueError, match=text):
        PipelineConfig(**change)


def test_draw_result_shape(shared_data):
    a, b = (load(shared_data, p) for p in PAIRS["temple_motion"])
    result = Pipeline().process(a, b)
    canvas = draw_result(a, b, result, epipolar_lines=5)
    assert canvas.shape == (a.shape[0], a.shape[1] + b.shape[1], 3) and canvas.dtype == np.uint8
    # something was drawn over the grey images (coloured pixels exist)
    assert np.any(canvas[..., 1].astype(int) - canvas[..., 0].astype(int) > 100)


def test_duplicate_correspondences_are_removed_best_first():
    from sepfm_ros.pipeline.features import Matches, unique_matches

    pts_a = np.array([[1.0, 2.0], [3.0, 4.0], [1.0, 2.0], [1.0, 2.0]])
    pts_b = np.array([[5.0, 6.0], [7.0, 8.0], [5.0, 6.0], [5.0, 9.0]])
    m = unique_matches(Matches(pts_a, pts_b, np.array([0.1, 0.2, 0.3, 0.4])))
    np.testing.assert_array_equal(m.ratio, [0.1, 0.2, 0.4])
    np.testing.assert_array_equal(m.pts_b, [[5.0, 6.0], [7.0, 8.0], [5.0, 9.0]])


def _reference_matches(pts_a, desc_a, pts_b, desc_b, features, ratio):
    """Lowe-ratio matches from OpenCV's BFMatcher.knnMatch, one Python loop (the plain way)."""
    norm = cv2.NORM_L2 if features == "sift" else cv2.NORM_HAMMING
    rows = []
    for m, n in cv2.BFMatcher(norm).knnMatch(desc_a, desc_b, k=2):
        r = m.distance / n.distance if n.distance > 0 else (0.0 if m.distance == 0 else 1.0)
        if r < ratio:
            rows.append((r, m.queryIdx, m.trainIdx))
    rows.sort(key=lambda row: row[0])  # stable: ties keep the order of image a
    seen_b, seen_pair, out = set(), set(), []
    for r, ia, ib in rows:
        if ib in seen_b:  # one match per point of b: the best
            continue
        seen_b.add(ib)
        pair = (*pts_a[ia], *pts_b[ib])
        if pair not in seen_pair:  # SIFT: one location, several orientations
            seen_pair.add(pair)
            out.append((r, ia, ib))
    out.sort(key=lambda row: row[0])
    return out


@pytest.mark.parametrize("features", [detector_param(f) for f in ("orb", "sift", "akaze")])
def test_vectorised_matching_equals_opencv_knn_matcher(shared_data, features):
    from sepfm_ros.pipeline.features import detect, make_detector, match_descriptors

    detector = make_detector(features, 500)
    names = ("kitti_stereo", "temple_motion")
    for (pa, da), (pb, db) in (
        (detect(load(shared_data, p), detector) for p in PAIRS[n]) for n in names
    ):
        for ratio in (0.6, 0.8, 1.0):
            m = match_descriptors(pa, da, pb, db, features, ratio)
            ref = _reference_matches(pa, da, pb, db, features, ratio)
            assert len(m) == len(ref) > 20
            np.testing.assert_array_equal(m.ratio, [r for r, _, _ in ref])
            np.testing.assert_array_equal(m.pts_a, pa[[ia for _, ia, _ in ref]])
            np.testing.assert_array_equal(m.pts_b, pb[[ib for _, _, ib in ref]])


@pytest.mark.parametrize("n_bytes", [1, 3, 32, 61])
def test_hamming_two_nearest_equals_opencv_knn_with_ties(n_bytes):
    """Few bits (many equal distances) and widths that are not a multiple of 8 bytes (AKAZE)."""
    from sepfm_ros.pipeline.features import _two_nearest_binary

    rng = np.random.default_rng(n_bytes)
    desc_a = rng.integers(0, 256, (300, n_bytes), dtype=np.uint8)
    desc_b = rng.integers(0, 256, (200, n_bytes), dtype=np.uint8)
    i1, d1, i2, d2 = _two_nearest_binary(desc_a, desc_b)
    knn = cv2.BFMatcher(cv2.NORM_HAMMING).knnMatch(desc_a, desc_b, k=2)
    np.testing.assert_array_equal(i1, [m.trainIdx for m, _ in knn])
    np.testing.assert_array_equal(d1, [m.distance for m, _ in knn])
    np.testing.assert_array_equal(i2, [n.trainIdx for _, n in knn])
    np.testing.assert_array_equal(d2, [n.distance for _, n in knn])


def test_match_and_estimate_on_two_threads_equal_process(shared_data):
    """The node's two stages (match pair n+1 while pair n is estimated) change no result."""
    from concurrent.futures import ThreadPoolExecutor

    pairs = [tuple(load(shared_data, p) for p in PAIRS[n]) for n in sorted(PAIRS)] * 2
    config = PipelineConfig(seed=5)
    expected = [Pipeline(config).process(a, b) for a, b in pairs]
    pipeline = Pipeline(config)
    got = []
    with ThreadPoolExecutor(1) as matcher:
        pending = matcher.submit(pipeline.match, *pairs[0])
        for k in range(len(pairs)):
            matched = pending.result()
            if k + 1 < len(pairs):
                pending = matcher.submit(pipeline.match, *pairs[k + 1])
            got.append(pipeline.estimate(matched))
    for e, g in zip(expected, got, strict=True):
        np.testing.assert_array_equal(e.estimate.F, g.estimate.F)
        np.testing.assert_array_equal(e.estimate.inliers, g.estimate.inliers)
        np.testing.assert_array_equal(e.matches.pts_b, g.matches.pts_b)
        assert e.estimate.hypotheses == g.estimate.hypotheses


def test_parallel_detection_equals_sequential(shared_data):
    """parallel_detect (the node's: image b detected on a helper thread) changes no result."""
    names = sorted(PAIRS)
    pairs = [tuple(load(shared_data, p) for p in PAIRS[n]) for n in names]
    config = PipelineConfig(seed=3)
    sequential, parallel = Pipeline(config), Pipeline(config, parallel_detect=True)
    for k, (a, b) in enumerate(pairs * 2):
        keys = (None, None) if k < len(pairs) else (("a", k % len(pairs)), ("b", k % len(pairs)))
        e, g = sequential.process(a, b, *keys), parallel.process(a, b, *keys)
        np.testing.assert_array_equal(e.matches.pts_a, g.matches.pts_a)
        np.testing.assert_array_equal(e.matches.pts_b, g.matches.pts_b)
        np.testing.assert_array_equal(e.estimate.F, g.estimate.F)
    assert parallel.images_detected == sequential.images_detected == 4 * len(pairs)
    parallel.update(max_features=500)  # the helper's detector follows the config
    np.testing.assert_array_equal(
        parallel.process(*pairs[0]).matches.pts_b,
        Pipeline(PipelineConfig(seed=3, max_features=500)).process(*pairs[0]).matches.pts_b,
    )
