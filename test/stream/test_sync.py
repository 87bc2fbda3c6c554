"""Approximate-time stereo pairing: jittered, missing and reordered stamps; exact mode; bounds."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from sepfm_ros.stream.sync import LEFT, RIGHT, ApproximateTimeSync

MS = 1_000_000
PERIOD = 100 * MS  # 10 Hz camera


def run(events, slop_ns, queue_size=10):
    """Feed (side, stamp) events in order; return the emitted (left_stamp, right_stamp) pairs."""
    sync = ApproximateTimeSync(slop_ns, queue_size)
    pairs = []
    for side, stamp in events:
        pair = sync.add(side, stamp, stamp)
        if pair is not None:
            pairs.append(pair)
    return pairs, sync


def interleave(left, right):
    return sorted([(LEFT, s) for s in left] + [(RIGHT, s) for s in right], key=lambda e: e[1])


def test_exact_stamps_pair_one_to_one():
    stamps = [k * PERIOD for k in range(20)]
    pairs, sync = run(interleave(stamps, stamps), slop_ns=0)
    assert pairs == [(s, s) for s in stamps]
    assert sync.stats.pairs == 20 and sync.stats.unmatched == 0


def test_slop_zero_rejects_any_difference():
    left = [k * PERIOD for k in range(10)]
    right = [s + 1 for s in left]  # 1 ns apart
    pairs, _ = run(interleave(left, right), slop_ns=0)
    assert pairs == []


def test_jittered_stamps_pair_within_slop():
    rng = np.random.default_rng(1)
    left = [k * PERIOD + int(rng.integers(-2 * MS, 2 * MS)) for k in range(50)]
    right = [k * PERIOD + int(rng.integers(-2 * MS, 2 * MS)) for k in range(50)]
    pairs, _ = run(interleave(left, right), slop_ns=5 * MS)
    assert pairs == list(zip(left, right, strict=True))


def test_jitter_beyond_slop_is_not_paired():
    left = [k * PERIOD for k in range(10)]
    right = [s + 7 * MS for s in left]
    pairs, sync = run(interleave(left, right), slop_ns=5 * MS)
    assert pairs == []
    assert sync.pending(LEFT) <= 10 and sync.pending(RIGHT) <= 10


def test_missing_messages_skip_only_their_pair():
    stamps = [k * PERIOD for k in range(20)]
    left = [s for k, s in enumerate(stamps) if k not in (3, 4, 11)]
    right = [s + MS for k, s in enumerate(stamps) if k not in (7, 11, 15)]
    pairs, sync = run(interleave(left, right), slop_ns=2 * MS)
    expected = [(s, s + MS) for k, s in enumerate(stamps) if k not in (3, 4, 7, 11, 15)]
    assert pairs == expected
    # the partners of missing messages were queued and discarded when a newer pair came
    assert sync.stats.unmatched == 4  # right 3, 4 and left 7, 15


def test_reordered_arrivals_within_a_side_still_pair():
    stamps = [k * PERIOD for k in range(6)]
    # right arrives first for every pair, and right 2 and 3 swap order in transport
    events = [(RIGHT, stamps[0]), (LEFT, stamps[0]), (RIGHT, stamps[1]), (LEFT, stamps[1])]
    events += [(RIGHT, stamps[3]), (RIGHT, stamps[2]), (LEFT, stamps[2]), (LEFT, stamps[3])]
    events += [
        (LEFT, stamps[4]),
        (RIGHT, stamps[4] + 2 * MS),
        (LEFT, stamps[5]),
        (RIGHT, stamps[5]),
    ]
    pairs, sync = run(events, slop_ns=3 * MS)
    assert pairs == [(s, s) for s in stamps[:4]] + [(stamps[4], stamps[4] + 2 * MS)] + [
        (stamps[5], stamps[5])
    ]
    assert sync.stats.late == 0


def test_arrival_older_than_the_last_pair_is_dropped_as_late():
    events = [(LEFT, 2 * PERIOD), (RIGHT, 2 * PERIOD), (LEFT, PERIOD), (RIGHT, PERIOD)]
    pairs, sync = run(events, slop_ns=MS)
    assert pairs == [(2 * PERIOD, 2 * PERIOD)]
    assert sync.stats.late == 2


def test_nearest_partner_is_chosen():
    # two right candidates inside the slop: the nearer one wins, the other is discarded
    events = [(RIGHT, 1000), (RIGHT, 1004), (LEFT, 1003)]
    pairs, _ = run(events, slop_ns=10)
    assert pairs == [(1003, 1004)]


def test_queue_is_bounded():
    events = [(LEFT, k * PERIOD) for k in range(100)]
    _, sync = run(events, slop_ns=MS, queue_size=5)
    assert sync.pending(LEFT) == 5 and sync.stats.evicted == 95


def test_configure_validates_and_shrinks():
    sync = ApproximateTimeSync(MS, 10)
    for k in range(8):
        sync.add(LEFT, k * PERIOD, k)
    sync.configure(0, 3)
    assert sync.pending(LEFT) == 3
    for bad in ((-1, 3), (0, 0)):
        try:
            sync.configure(*bad)
        except ValueError:
            continue
        raise AssertionError(f"configure{bad} did not raise")


@settings(max_examples=200, deadline=None)
@given(
    st.lists(
        st.tuples(st.sampled_from([LEFT, RIGHT]), st.integers(0, 2_000)), min_size=0, max_size=60
    ),
    st.integers(0, 30),
    st.integers(1, 8),
)
def test_properties_of_any_arrival_order(events, slop, queue_size):
    pairs, sync = run(events, slop, queue_size)
    for left, right in pairs:
        assert abs(left - right) <= slop
    # strictly increasing stamps on both sides: no message is used twice, never out of order
    for (l0, r0), (l1, r1) in zip(pairs, pairs[1:], strict=False):
        assert l1 > l0 and r1 > r0
    assert sync.pending(LEFT) <= queue_size and sync.pending(RIGHT) <= queue_size
    # every received message is accounted for exactly once
    s = sync.stats
    total = sum(s.received)
    assert total == 2 * s.pairs + s.unmatched + s.evicted + s.late + sync.pending(LEFT) + (
        sync.pending(RIGHT)
    )
