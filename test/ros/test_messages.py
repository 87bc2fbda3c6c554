"""Output messages: the typed answer of a pair (:mod:`sepfm_ros.ros.session.answer`) and the ground
truth's F image (pure functions, no DDS)."""

from __future__ import annotations

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import Image
from std_msgs.msg import Header

from sepfm_msgs.msg import MatchArray, TwoViewEstimate
from sepfm_ros.geometry import Estimate
from sepfm_ros.geometry.estimate import StatusCode
from sepfm_ros.pipeline.features import Matches
from sepfm_ros.pipeline.pipeline import MatchedPair, Pipeline, PipelineConfig, PipelineResult
from sepfm_ros.ros.bags.results import match_table
from sepfm_ros.ros.msgs.fundamental import (
    fundamental_from_image,
    fundamental_from_msg,
    fundamental_to_image,
)
from sepfm_ros.ros.msgs.headers import stamp_ns
from sepfm_ros.ros.msgs.image_conversion import numpy_to_image
from sepfm_ros.ros.session.answer import (
    ESTIMATOR_INPUT,
    AnswerSettings,
    BadInput,
    DecodedPair,
    PairHeaders,
    answer_matched,
    decode_pair,
    estimate_message,
    failure_answer,
    internal_error_answer,
    match_array,
)
from sepfm_ros.ros.session.parameters import parse_params
from sepfm_ros.ros.session.session import Session

HEADER = Header(stamp=Time(sec=12, nanosec=345), frame_id="left_cam")
HEADERS = PairHeaders(HEADER, HEADER, Header(stamp=Time(sec=12, nanosec=999), frame_id="right_cam"))
SETTINGS = AnswerSettings("orb", "sep5", publish_unreliable=True, threshold_px=1.0)


def make_result(with_f: bool = True) -> PipelineResult:
    rng = np.random.default_rng(0)
    pts_a, pts_b = rng.uniform(0, 600, (5, 2)), rng.uniform(0, 400, (5, 2))
    F = np.arange(9, dtype=np.float64).reshape(3, 3)
    F /= np.linalg.norm(F)
    est = Estimate(
        F=F if with_f else None,
        inliers=np.array([True, False, True, True, False]),
        hypotheses=17,
        stage1_hypotheses=5,
        stage2_hypotheses=12,
        line_pair=((0.0, 1.0, -10.0), (0.6, 0.8, -3.0)) if with_f else None,
        line_inliers=np.array([0, 2]),
        method="sep5",
    )
    if not with_f:
        est.set_status(StatusCode.TOO_FEW_MATCHES, "no model")
    errors = rng.uniform(0, 3, 5) if with_f else np.full(5, np.nan)
    on_line = np.array([True, False, True, False, False])
    timings = {"features": 3.0, "match": 1.5, "total": 9.0}
    return PipelineResult(
        Matches(pts_a, pts_b, np.linspace(0.1, 0.5, 5)), est, errors, on_line, (640, 480),
        (320, 240), timings,
    )  # fmt: skip


def test_fundamental_image_round_trip_through_cdr():
    F = make_result().estimate.F
    msg = deserialize_message(serialize_message(fundamental_to_image(F, HEADER)), Image)
    assert (msg.encoding, msg.height, msg.width, msg.step) == ("64FC1", 3, 3, 24)
    assert msg.header.frame_id == "left_cam" and msg.header.stamp.nanosec == 345
    np.testing.assert_array_equal(fundamental_from_image(msg), F)


def test_fundamental_image_rejects_bad_f():
    with pytest.raises(ValueError):
        fundamental_to_image(np.full((3, 3), np.nan), HEADER)
    with pytest.raises(ValueError):
        fundamental_to_image(np.eye(2), HEADER)


def test_estimate_message_fields_through_cdr():
    result = make_result()
    answer_matches = match_array(HEADERS, result)
    msg = estimate_message(HEADERS, result, SETTINGS, "image", None, calibration_input=False)
    msg = deserialize_message(serialize_message(msg), TwoViewEstimate)
    assert msg.header.frame_id == "left_cam" and stamp_ns(msg.header.stamp) == 12_000_000_345
    assert stamp_ns(msg.stamp_a) == 12_000_000_345 and stamp_ns(msg.stamp_b) == 12_000_000_999
    assert (msg.frame_id_a, msg.frame_id_b) == ("left_cam", "right_cam")
    assert (msg.width_a, msg.height_a, msg.width_b, msg.height_b) == (640, 480, 320, 240)
    assert msg.has_f and msg.status == TwoViewEstimate.STATUS_OK and msg.status_text == "ok"
    np.testing.assert_array_equal(fundamental_from_msg(msg), result.estimate.F)
    assert (msg.method, msg.features, msg.coordinates) == ("sep5", "orb", "image")
    assert (msg.matches, msg.inliers, msg.hypotheses) == (5, 3, 17)
    assert (msg.stage1_hypotheses, msg.stage2_hypotheses, msg.line_inliers) == (5, 12, 2)
    inlier_errors = result.errors[result.estimate.inliers]
    assert msg.inlier_error_px == pytest.approx(float(np.median(inlier_errors)))
    assert msg.has_line_pair and list(msg.line_a) == [0.0, 1.0, -10.0]
    assert list(msg.line_b) == [0.6, 0.8, -3.0]
    assert {t.stage: t.ms for t in msg.timings} == {"features": 3.0, "match": 1.5, "total": 9.0}
    assert msg.pose_kind == TwoViewEstimate.POSE_NONE and msg.pose_status == ""
    assert np.isnan(msg.log10_nfa)
    assert len(answer_matches.matches) == 5


def test_unreliable_f_is_given_only_when_wanted():
    result = make_result()
    result.estimate.set_status(StatusCode.DEGENERATE, "degenerate: dominant plane")
    strict = AnswerSettings("orb", "sep5", publish_unreliable=False, threshold_px=1.0)
    msg = estimate_message(HEADERS, result, strict, "image", None, calibration_input=False)
    assert not msg.has_f and not np.any(msg.f) and msg.status == TwoViewEstimate.STATUS_DEGENERATE
    assert msg.status_text == "degenerate: dominant plane"
    msg = estimate_message(HEADERS, result, SETTINGS, "image", None, calibration_input=False)
    assert msg.has_f and msg.status == TwoViewEstimate.STATUS_DEGENERATE


def test_estimate_without_f():
    result = make_result(with_f=False)
    msg = estimate_message(HEADERS, result, SETTINGS, "image", None, calibration_input=True)
    assert not msg.has_f and msg.status == TwoViewEstimate.STATUS_TOO_FEW_MATCHES
    assert msg.status_text == "no model" and not msg.has_line_pair and not any(msg.line_a)
    assert np.isnan(msg.inlier_error_px)
    assert msg.pose_kind == TwoViewEstimate.POSE_NONE and msg.pose_status != ""


def test_match_array_through_cdr():
    result = make_result()
    msg = deserialize_message(serialize_message(match_array(HEADERS, result)), MatchArray)
    assert msg.header.frame_id == "left_cam" and stamp_ns(msg.stamp_b) == 12_000_000_999
    table = match_table(msg)
    np.testing.assert_array_equal(table["u_a"], result.matches.pts_a[:, 0])
    np.testing.assert_array_equal(table["v_b"], result.matches.pts_b[:, 1])
    np.testing.assert_array_equal(table["error_px"], result.errors)
    np.testing.assert_array_equal(table["inlier"], result.estimate.inliers)
    np.testing.assert_array_equal(table["on_line"], result.on_line)


def test_failure_records():
    bad = BadInput("size_change", "the camera's frame size changed", ((640, 480), (320, 240)))
    answer = failure_answer(HEADERS, bad, SETTINGS)
    msg = deserialize_message(serialize_message(answer.estimate), TwoViewEstimate)
    assert msg.status == TwoViewEstimate.STATUS_BAD_INPUT and msg.bad_input_kind == "size_change"
    assert msg.status_text == "bad input (size_change): the camera's frame size changed"
    assert (msg.width_a, msg.height_a, msg.width_b, msg.height_b) == (640, 480, 320, 240)
    assert not msg.has_f and msg.matches == 0 and np.isnan(msg.inlier_error_px)
    assert (msg.method, msg.features) == ("sep5", "orb") and stamp_ns(msg.stamp_a) == 12_000_000_345
    assert answer.matches.matches == [] and answer.result is None
    internal = internal_error_answer(HEADERS, RuntimeError("boom"), SETTINGS).estimate
    assert internal.status == TwoViewEstimate.STATUS_INTERNAL_ERROR
    assert internal.status_text == "internal error: RuntimeError: boom"
    assert internal.bad_input_kind == "" and not internal.has_f


def test_decode_pair_refuses_a_frame_size_change_of_one_camera_only():
    big = numpy_to_image(np.zeros((48, 64), np.uint8), "mono8", HEADER)
    small = numpy_to_image(np.zeros((24, 32), np.uint8), "mono8", HEADER)
    bad = decode_pair(big, small, stereo=False)
    assert isinstance(bad, BadInput) and bad.kind == "size_change"
    assert bad.sizes == ((64, 48), (32, 24))
    decoded = decode_pair(big, small, stereo=True)  # two cameras of a rig may differ
    assert isinstance(decoded, DecodedPair) and decoded.images[1].shape == (24, 32)
    broken = numpy_to_image(np.zeros((48, 64), np.uint8), "mono8", HEADER)
    broken.data = bytes(10)
    bad = decode_pair(broken, big, stereo=True)
    assert isinstance(bad, BadInput) and bad.kind == "short_data"


def test_stamp_ns():
    from builtin_interfaces.msg import Time

    from sepfm_ros.ros.msgs.headers import stamp_ns

    assert stamp_ns(Time(sec=3, nanosec=250)) == 3_000_000_250
    assert stamp_ns(Time(sec=-2, nanosec=999_999_999)) == -1_000_000_001


def test_an_error_while_answering_gives_the_internal_error_record():
    """Images the pipeline cannot take (7 channels) make OpenCV raise inside the answer path:
    the pair still gets its record, STATUS_INTERNAL_ERROR with the reason, and no matches."""
    images = (np.zeros((40, 40, 7)), np.zeros((40, 40, 7)))
    session = Session(parse_params([]), True, ["left/image_raw", "right/image_raw"])
    answer = session.answer_decoded(HEADERS, DecodedPair(images, 0.0))
    assert answer.estimate.status == TwoViewEstimate.STATUS_INTERNAL_ERROR
    assert answer.estimate.status_text.startswith("internal error: error: OpenCV")
    assert answer.error is not None and answer.result is None
    assert answer.matches.matches == [] and not answer.estimate.has_f


def test_matches_the_estimator_refuses_are_bad_input_of_their_own_kind():
    """A non-finite matched point (what a wild distortion model can make of a pixel) reaches
    the estimator, which refuses it: STATUS_BAD_INPUT with kind estimator_input (the kind the
    node counts in /diagnostics), the reason, and the matches it was given."""
    rng = np.random.default_rng(3)
    pts_a = rng.uniform(0, 600, (40, 2))
    pts_b = pts_a + 1.0
    pts_a[3, 0] = np.nan
    config = PipelineConfig()
    matched = MatchedPair(
        Matches(pts_a, pts_b, np.ones(40)), (640, 480), (640, 480), {}, config, 0.0
    )
    answer = answer_matched(Pipeline(config), HEADERS, matched, AnswerSettings.of(config, True))
    msg = answer.estimate
    assert msg.status == TwoViewEstimate.STATUS_BAD_INPUT and msg.bad_input_kind == ESTIMATOR_INPUT
    assert "NaN or inf" in msg.status_text and not msg.has_f
    assert msg.matches == 40 and len(answer.matches.matches) == 40


@pytest.mark.parametrize("skipped", [True, False])
def test_estimate_message_says_whether_the_line_search_was_skipped(skipped):
    """``Estimate.line_search_skipped`` (the escape) reaches ``TwoViewEstimate`` through CDR, apart
    from ``fallback`` (no usable line pair found)."""
    result = make_result()
    result.estimate.line_search_skipped = skipped
    msg = estimate_message(HEADERS, result, SETTINGS, "image", None, calibration_input=False)
    msg = deserialize_message(serialize_message(msg), TwoViewEstimate)
    assert msg.line_search_skipped is skipped
    assert msg.fallback is False
