"""The node's scheduling rules under load (sepfm_ros.stream.scheduling; no DDS).

The live consequences (latency under input at twice the processing rate, every pair answered
when the node keeps up) are tested in test_robustness_live.py and test_node_live.py.
"""

from __future__ import annotations

import pytest

from sepfm_ros.stream.scheduling import (
    FRESH_AGE_SHARE,
    FRESHER_WAIT_SLACK_SHARE,
    RecentPeriod,
    fresher_pair_wait,
    is_saturated,
)


def test_saturated_only_when_pairs_come_faster_than_processing():
    assert is_saturated(period_s=0.010, processing_s=0.020)
    assert not is_saturated(period_s=0.033, processing_s=0.020)
    assert not is_saturated(period_s=0.020, processing_s=0.020)


@pytest.mark.parametrize("age_s", [0.0, 0.001, FRESH_AGE_SHARE * 0.010])
def test_a_fresh_pair_is_taken_at_once(age_s):
    assert fresher_pair_wait(age_s, period_s=0.010) == 0.0


def test_a_stale_pair_waits_until_the_next_is_due_plus_slack():
    period = 0.010
    # 6 ms old: the next pair is due in 4 ms, plus half a period of jitter
    assert fresher_pair_wait(0.006, period) == pytest.approx(
        0.004 + FRESHER_WAIT_SLACK_SHARE * period
    )
    # older than a period (the next one is late): only the slack
    assert fresher_pair_wait(0.015, period) == pytest.approx(FRESHER_WAIT_SLACK_SHARE * period)
    # the wait never exceeds the period plus the slack
    ages = [0.0026 + 0.0005 * k for k in range(40)]
    assert (
        max(fresher_pair_wait(a, period) for a in ages) <= (1 + FRESHER_WAIT_SLACK_SHARE) * period
    )


def test_recent_period_is_the_mean_over_a_span():
    period = RecentPeriod(size=9, warmup=4)
    for k in range(3):
        period.add(0.1 * k)
    assert not period.ready
    period.add(0.3)
    assert period.ready and period.value == pytest.approx(0.1)
    for k in range(4, 20):
        period.add(0.1 * k)
    assert period.value == pytest.approx(0.1)  # only the last 9 events count


def test_bursts_do_not_pass_for_a_fast_input():
    # pairs delivered two at once every 0.6 s (a transport delay): the median interval would be
    # 1 ms, the input period is 0.3 s, and a node taking 50 ms per pair keeps up
    period = RecentPeriod()
    t = 0.0
    for _ in range(6):
        t += 0.6
        period.add(t)
        period.add(t + 0.001)
    assert period.value == pytest.approx(0.6 * 4 / 8, rel=0.01)
    assert not is_saturated(period.value, processing_s=0.050)
