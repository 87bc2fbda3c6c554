"""The stamp-sequence gap counter (no ROS): the period from the stamps alone, k periods apart =
k - 1 frames missing, pauses and stamps going back."""

import re

import numpy as np
import pytest

from sepfm_ros.stream.frame_gaps import StampGaps, estimate_period_ns
from sepfm_ros.stream.health import WARN, Health

PERIOD = 100_000_000  # 10 Hz


def _feed(gaps: StampGaps, kept: list[int], jitter_ns: int = 0, seed: int = 0) -> int:
    rng = np.random.default_rng(seed)
    total = 0
    for k in kept:
        stamp = 1_000_000_000 + k * PERIOD + int(rng.integers(-jitter_ns, jitter_ns + 1))
        total += gaps.add("image", stamp)
    return total


def test_every_frame_received_counts_nothing():
    gaps = StampGaps()
    assert _feed(gaps, list(range(100)), jitter_ns=5_000_000) == 0
    assert gaps.period_s("image") == pytest.approx(0.1, rel=0.1)
    assert gaps.share_missing("image") == 0.0


def test_a_gap_of_k_periods_is_k_minus_one_missing_frames():
    kept = [k for k in range(200) if k % 10 not in (3, 4, 7)]  # 3 of every 10 frames lost
    gaps = StampGaps()
    missing = _feed(gaps, kept, jitter_ns=3_000_000, seed=1)
    # the first MIN_INTERVALS intervals only estimate the period: at most the frames before
    # them go uncounted
    assert 55 <= missing <= 60
    assert gaps.missing("image") == missing
    assert gaps.share_missing("image") == pytest.approx(0.3, abs=0.02)


def test_period_found_when_no_two_consecutive_frames_arrive():
    """A link carrying about a quarter of the frames: intervals of 3, 4 and 5 periods."""
    rng = np.random.default_rng(2)
    kept, k = [], 0
    while k < 400:
        kept.append(k)
        k += int(rng.integers(3, 6))
    gaps = StampGaps()
    missing = _feed(gaps, kept, jitter_ns=2_000_000, seed=3)
    assert gaps.period_s("image") == pytest.approx(0.1, rel=0.05)
    expected = kept[-1] - len(kept) + 1
    assert expected - 25 <= missing <= expected


def test_estimate_period_needs_intervals():
    assert estimate_period_ns([PERIOD] * 3) is None
    assert estimate_period_ns([3 * PERIOD, 4 * PERIOD, 3 * PERIOD, 5 * PERIOD]) == PERIOD


def test_pause_and_stamps_going_back_are_not_missing_frames():
    gaps = StampGaps(pause_s=1.0)
    assert _feed(gaps, list(range(20))) == 0
    assert gaps.add("image", 1_000_000_000 + 60 * PERIOD) == 0  # a 4 s pause
    assert gaps.add("image", 500_000_000) == 0  # a looped bag
    assert _feed(gaps, list(range(20))) == 0
    assert gaps.missing("image") == 0


def test_health_warns_naming_the_share_missing():
    now = [0.0]
    health = Health(("image",), 1.0, clock=lambda: now[0])
    for k in range(60):
        if k % 2 and k > 10:
            continue  # every other frame missing after the first 10
        now[0] = k * 0.1
        health.frame_stamp("image", 1_000_000_000 + k * PERIOD)
    level, message = health.level()
    assert level == WARN
    found = re.search(r"(\d+) of (\d+) frames \((\d+)%\) missing from the camera stamp", message)
    assert found, message
    missing, total, percent = map(int, found.groups())
    assert missing == 24 and 24 + 24 <= total <= 24 + 35  # 24 even frames after the gaps began
    assert percent == round(100 * missing / total)
    values = health.values()
    assert values["frames_missing"] == values["frames_missing_image"] == 24
    assert values["problems_recent"] == 24
