"""The node's parts alone, without DDS: pairing (stamp jumps, nearest stereo pairing), the
scheduler with an injected clock, health (recent window, levels, stalls, throttled logs) and the
QoS choice from the publishers' profiles."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from sepfm_ros.stream.health import ERROR, OK, WARN, Health, LogThrottle, RecentEvents
from sepfm_ros.stream.pairing import Frame, MotionPairing, StereoPairing, stamp_order_effects
from sepfm_ros.stream.scheduling import PairScheduler
from sepfm_ros.stream.sync import LEFT, RIGHT

MS = 1_000_000
S = 1_000_000_000


class FakeClock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


# --------------------------------------------------------------------------- pairing
def test_motion_pairing_restarts_after_a_jump_back_and_skips_small_steps_back():
    pairing: MotionPairing[str] = MotionPairing(frame_gap=1, jump_back_s=1.0)
    outs = [pairing.add(Frame(f"f{k}", 50 * S + k * 100 * MS)) for k in range(5)]
    assert outs[0].pair is None
    assert [o.pair[0].item for o in outs[1:]] == ["f0", "f1", "f2", "f3"]
    # a reordered frame (0.2 s back): skipped as late, history kept
    late = pairing.add(Frame("old", 50 * S + 200 * MS))
    assert late.late and late.pair is None and not late.reset
    # the bag loops: 50.4 s -> 50.0 s is 0.4 s back (late); 10 s back resets
    jump = pairing.add(Frame("loop0", 40 * S))
    assert jump.reset and jump.pair is None and not jump.late
    after = pairing.add(Frame("loop1", 40 * S + 100 * MS))
    assert after.pair is not None
    assert (after.pair[0].item, after.pair[1].item) == ("loop0", "loop1")


def test_motion_pairing_frame_gap():
    pairing: MotionPairing[int] = MotionPairing(frame_gap=3)
    pairs = [pairing.add(Frame(k, k * S)).pair for k in range(6)]
    assert [p is None for p in pairs] == [True, True, True, False, False, False]
    assert [(p[0].item, p[1].item) for p in pairs[3:]] == [(0, 3), (1, 4), (2, 5)]


def test_stereo_pairing_nearest_right_at_half_period_slop_with_lag():
    """10 Hz, right stamps 12 ms behind the left, arriving in either order, some frames lost:
    with a slop of half the period every pair formed is a left frame with its own right."""
    pairing: StereoPairing[str] = StereoPairing(slop_ns=50 * MS, queue_size=10)
    lost = {3: RIGHT, 6: LEFT, 7: RIGHT}
    pairs = []
    for k in range(12):
        events = [(LEFT, k * 100 * MS), (RIGHT, k * 100 * MS + 12 * MS)]
        if k % 2:
            events.reverse()
        for side, stamp in events:
            if lost.get(k) == side:
                continue
            out = pairing.add(side, Frame(f"{'LR'[side]}{k}", stamp))
            if out.pair is not None:
                pairs.append((out.pair[0].item, out.pair[1].item))
    expected = [(f"L{k}", f"R{k}") for k in range(12) if k not in lost]
    assert pairs == expected
    assert pairing.offset_ns() == 12 * MS


@pytest.mark.parametrize("right_first", [False, True])
def test_stereo_pairing_default_slop_pairs_nothing_with_a_12ms_lag(right_first):
    pairing: StereoPairing[str] = StereoPairing(slop_ns=5 * MS, queue_size=10)
    for k in range(5):
        events = [(LEFT, k * 100 * MS), (RIGHT, k * 100 * MS + 12 * MS)]
        for side, stamp in reversed(events) if right_first else events:
            assert pairing.add(side, Frame("lr"[side], stamp)).pair is None
            if k:  # the offset of a frame's two images, whichever arrived first
                assert pairing.offset_ns() == 12 * MS


def test_stereo_pairing_restarts_after_a_jump_back():
    pairing: StereoPairing[str] = StereoPairing(slop_ns=5 * MS, queue_size=10, jump_back_s=1.0)
    for k in range(3):
        pairing.add(LEFT, Frame("l", 20 * S + k * 100 * MS))
        assert pairing.add(RIGHT, Frame("r", 20 * S + k * 100 * MS)).pair is not None
    # looped: both sides restart at 10 s; without the reset every frame would be "late"
    out = pairing.add(LEFT, Frame("l0", 10 * S))
    assert out.reset
    out = pairing.add(RIGHT, Frame("r0", 10 * S + 1 * MS))
    assert not out.reset and out.pair is not None
    assert (out.pair[0].item, out.pair[1].item) == ("l0", "r0")
    # a straggler of the old run (right, 20.3 s) resets once more; pairing goes on after it
    assert pairing.add(RIGHT, Frame("straggler", 20 * S + 300 * MS)).pair is None
    pairing.add(LEFT, Frame("l1", 10 * S + 100 * MS))
    out = pairing.add(RIGHT, Frame("r1", 10 * S + 100 * MS))
    assert out.pair is not None and out.pair[0].item == "l1"


def test_stereo_pairing_a_topic_delivered_seconds_late_is_not_a_jump_back():
    """10 Hz; the right camera's frames arrive 1.5 s (15 frames) after the left's with the same
    stamps: each side's stamps only go forward, so nothing resets and every frame pairs."""
    pairing: StereoPairing[str] = StereoPairing(slop_ns=5 * MS, queue_size=20, jump_back_s=1.0)
    pairs, resets = [], 0
    for k in range(40):
        events = [(LEFT, k)] + ([(RIGHT, k - 15)] if k >= 15 else [])
        for side, j in events:
            out = pairing.add(side, Frame(f"{'LR'[side]}{j}", 30 * S + j * 100 * MS))
            resets += out.reset
            if out.pair is not None:
                pairs.append((out.pair[0].item, out.pair[1].item))
    assert resets == 0
    assert pairs == [(f"L{j}", f"R{j}") for j in range(25)]


def test_stereo_pairing_reset_keeps_the_other_sides_new_frames():
    """A bag loops and the right camera's new frames arrive before the left's first one: the
    right camera's jump back drops the old run's queued left frame and forgets the left's newest
    stamp, so the left's first new frame pairs at once and no pair is lost."""
    pairing: StereoPairing[str] = StereoPairing(slop_ns=5 * MS, queue_size=10, jump_back_s=1.0)
    for k in range(3):
        pairing.add(LEFT, Frame("l", 20 * S + k * 100 * MS))
        assert pairing.add(RIGHT, Frame("r", 20 * S + k * 100 * MS)).pair is not None
    pairing.add(LEFT, Frame("l-old", 20 * S + 300 * MS))  # unpaired frame of the old run
    # right loops first: its own jump back; the queued old left frame is dropped
    assert pairing.add(RIGHT, Frame("r0", 10 * S)).reset
    assert pairing.add(RIGHT, Frame("r1", 10 * S + 100 * MS)).pair is None
    out = pairing.add(LEFT, Frame("l0", 10 * S))
    assert not out.reset and out.pair is not None
    assert (out.pair[0].item, out.pair[1].item) == ("l0", "r0")
    out = pairing.add(LEFT, Frame("l1", 10 * S + 100 * MS))
    assert not out.reset and out.pair is not None
    assert (out.pair[0].item, out.pair[1].item) == ("l1", "r1")
    assert pairing.stats.late == 0
    # a late left straggler of the old run (20.4 s) is newer: queued, pairs with nothing; the
    # next new left frame is then a jump back that keeps the right's queued new frame
    assert pairing.add(LEFT, Frame("l-straggler", 20 * S + 400 * MS)).pair is None
    assert pairing.add(RIGHT, Frame("r2", 10 * S + 200 * MS)).pair is None
    out = pairing.add(LEFT, Frame("l2", 10 * S + 200 * MS))
    assert out.reset and out.pair is not None
    assert (out.pair[0].item, out.pair[1].item) == ("l2", "r2")


def test_stamp_order_effects_counts_what_the_pairing_skips_and_restarts_on():
    ms = [int(v * 1e9) for v in (1.0, 1.4, 1.2, 1.3, 1.6)]  # 1.2 and 1.3: not after 1.4
    assert stamp_order_effects(ms) == (2, 0)
    looped = [int(v * 1e9) for v in (0.0, 0.5, 1.0, 1.5, 0.0, 0.5, 0.5, 1.0)]
    assert stamp_order_effects(looped) == (1, 1)  # the restart, then a repeat
    assert stamp_order_effects(looped, jump_back_s=2.0) == (4, 0)  # 0.0, 0.5, 0.5, 1.0 late
    pairing: MotionPairing[int] = MotionPairing(frame_gap=1, jump_back_s=1.0)
    outs = [pairing.add(Frame(k, s)) for k, s in enumerate(looped)]
    assert (sum(o.late for o in outs), sum(o.reset for o in outs)) == (1, 1)


# --------------------------------------------------------------------------- scheduler
def test_scheduler_owed_pair_is_never_replaced_and_newest_wins_behind_it():
    clock = FakeClock()
    sched: PairScheduler[str, str] = PairScheduler(clock)
    with sched._cond:
        assert sched.match_decision(clock()) == (None, None)  # idle: waits for input
    assert not sched.offer("p1", clock())  # owed an answer (the node is idle)
    assert not sched.offer("p2", clock())
    assert sched.offer("p3", clock())  # replaces p2 in the slot: dropped
    with sched._cond:
        first, _ = sched.match_decision(clock())
        assert first.job == "p1"
        sched._matched = "m1"  # hand-over slot full: the match thread waits
        assert sched.match_decision(clock()) == (None, None)
        sched._matched = None
        second, _ = sched.match_decision(clock())
    assert second.job == "p3"
    assert sched.dropped == 1 and sched.offered == 3


def test_scheduler_keeping_up_starts_matching_shortly_before_the_estimate_ends():
    clock = FakeClock()
    sched: PairScheduler[str, str] = PairScheduler(clock)
    for _ in range(3):
        sched.match_s.add(0.010)
        sched.estimate_s.add(0.020)
    for k in range(5):  # input every 100 ms: the node keeps up
        sched.period_s.add(clock.t - 0.5 + 0.1 * k)
    sched.put_matched("m", 0.010)
    taken = sched.take_for_estimate()
    assert taken == ("m", clock.t)
    sched.offer("next", clock())
    with sched._cond:
        item, wait = sched.match_decision(clock())
    # estimate expected to take 20 ms: start 4 ms before its end
    assert item is None and wait == pytest.approx(0.016)
    clock.t += 0.017
    with sched._cond:
        item, wait = sched.match_decision(clock())
    assert item.job == "next" and wait is None


def test_scheduler_saturated_waits_for_a_fresher_pair_once():
    clock = FakeClock()
    sched: PairScheduler[str, str] = PairScheduler(clock)
    for _ in range(3):
        sched.match_s.add(0.010)
        sched.estimate_s.add(0.020)
    for k in range(8):  # input every 10 ms, processing 30 ms: saturated
        sched.offer(f"p{k}", clock.t)
        with sched._cond:  # keep the slot: take owed pairs away
            sched._owed = None
        clock.t += 0.010
    with sched._cond:
        assert sched.saturated()
        item, wait = sched.match_decision(clock())
        # p7 is 10 ms old (> a quarter period): wait for the next one, due now, + half a period
        assert item is None and wait == pytest.approx(0.005)
        item, wait = sched.match_decision(clock())  # passed over once only
        assert item.job == "p7"


def test_scheduler_stop_wakes_both_workers():
    sched: PairScheduler[str, str] = PairScheduler()
    sched.stop()
    assert sched.take_for_match() is None
    assert sched.take_for_estimate() is None


# --------------------------------------------------------------------------- health
def test_recent_events_forget_old_ones():
    events = RecentEvents(window_s=10.0)
    events.add("bad_step", 0.0)
    events.add("bad_step", 5.0, count=3)
    assert events.counts(9.0) == {"bad_step": 4}
    assert events.counts(12.0) == {"bad_step": 3}
    assert events.counts(16.0) == {}


def test_one_bad_message_does_not_latch_warn():
    clock = FakeClock()
    health = Health(("image",), input_timeout_s=0.5, window_s=10.0, clock=clock)
    assert health.level() == (OK, "ok")
    health.problem("bad_step")
    level, message = health.level()
    assert level == WARN and "1 bad inputs" in message and "bad_step" in message
    clock.t += 10.5
    assert health.level() == (OK, "ok")
    assert health.values()["errors_bad_step"] == 1  # lifetime counter kept


def test_internal_errors_are_error_level_and_lost_samples_say_the_fix():
    clock = FakeClock()
    health = Health(("image",), input_timeout_s=0.5, clock=clock)
    health.lost_samples("/cam/image_raw", 3)
    level, message = health.level()
    assert level == WARN and "3 input samples lost" in message and "reliable" in message
    health.problem("internal_ValueError")
    level, message = health.level()
    assert level == ERROR and "internal_ValueError" in message
    values = health.values()
    assert values["lost_samples"] == 3 and values["lost_samples_/cam/image_raw"] == 3


def test_stereo_inputs_without_pairs_warn_with_the_measured_offset():
    clock = FakeClock()
    health = Health(("left", "right"), input_timeout_s=0.5, clock=clock)
    for _ in range(10):  # 10 Hz, both streaming, no pair
        health.input("left")
        health.input("right")
        health.stereo_offset(12 * MS)
        clock.t += 0.1
    stall = health.stall()
    assert stall is not None and "+12.0 ms" in stall and "sync_slop_s" in stall
    assert "0.013" in stall
    assert health.level(stall)[0] == WARN
    health.pair_formed()
    assert health.stall() is None


def _paired_stereo_health() -> tuple[FakeClock, Health]:
    """Health of a stereo input after 1 s of both cameras at 10 Hz, every frame paired."""
    clock = FakeClock()
    health = Health(("left", "right"), input_timeout_s=0.5, clock=clock)
    for _ in range(10):
        health.input("left")
        health.input("right")
        health.pair_formed()
        clock.t += 0.1
    return clock, health


def test_stereo_camera_silent_is_a_stall():
    clock, health = _paired_stereo_health()
    for _ in range(10):
        health.input("left")
        health.pair_formed()
        clock.t += 0.1
    stall = health.stall()
    assert stall is not None and "right camera silent" in stall
    clock.t += 5.0  # then the left camera stops too: no camera is arriving, no stall
    assert health.stall() is None


def test_both_cameras_stopping_apart_is_not_a_stall():
    """The two streams end 1 s apart (a loaded receiver drained one queue later): once both
    are silent, the gap between their last images says nothing about either camera."""
    clock, health = _paired_stereo_health()
    clock.t += 1.0
    health.input("left")
    clock.t += 10.0
    assert health.stall() is None
    assert health.level(health.stall())[0] == 0


def test_log_throttle_lets_a_recurring_problem_through_periodically():
    throttle = LogThrottle(period_s=10.0)
    assert throttle.admit("bad_step", 0.0) == 0
    assert throttle.admit("bad_step", 1.0) is None
    assert throttle.admit("bad_step", 2.0) is None
    assert throttle.admit("zero_size", 2.0) == 0  # kinds are independent
    assert throttle.admit("bad_step", 10.5) == 2  # logged again, with the count held back


def test_log_throttle_message_says_what_was_held_back():
    throttle = LogThrottle(period_s=10.0)
    assert throttle.message("decode", "bad", 0.0) == (
        "bad [logged at most every 10 s, counted in /diagnostics]"
    )
    assert throttle.message("decode", "bad", 1.0) is None
    later = throttle.message("decode", "bad", 11.0)
    assert later is not None and later.startswith("bad [1 more since the last report]")


# --------------------------------------------------------------------------- QoS
def test_offered_reliability_matches_every_publisher():
    from rclpy.qos import ReliabilityPolicy

    from sepfm_ros.ros.node.subscriptions import offered_reliability

    rel = SimpleNamespace(reliability=ReliabilityPolicy.RELIABLE)
    be = SimpleNamespace(reliability=ReliabilityPolicy.BEST_EFFORT)
    assert offered_reliability([rel, rel]) == ReliabilityPolicy.RELIABLE
    assert offered_reliability([rel, be]) == ReliabilityPolicy.BEST_EFFORT
    assert offered_reliability([be]) == ReliabilityPolicy.BEST_EFFORT
