"""Gaps in a stream of scans: the one rule of info, training windows and the evaluation."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from lidarflow.data.gaps import frames_after_gaps
from lidarflow.stamps import HISTORY, MIN_STEPS

MS = 1_000_000


def stamps(steps_ms: list[float], start_ms: float = 1000.0) -> list[int]:
    return [int(v * MS) for v in np.cumsum([start_ms, *steps_ms])]


def test_steady_stream_has_no_gap():
    assert frames_after_gaps(stamps([100.0] * 50)) == []


def test_a_long_step_is_a_gap_and_only_that_one():
    steps = [100.0] * 10 + [1000.0] + [100.0] * 10
    assert frames_after_gaps(stamps(steps)) == [11]


def test_threshold_is_relative_to_the_rate():
    # 240 ms after 100 ms steps is no gap (2.4 periods); 260 ms is (2.6 periods)
    assert frames_after_gaps(stamps([100.0] * 5 + [240.0] + [100.0] * 3)) == []
    assert frames_after_gaps(stamps([100.0] * 5 + [260.0] + [100.0] * 3)) == [6]
    # the same 260 ms at 5 Hz is a normal step
    assert frames_after_gaps(stamps([200.0] * 5 + [260.0] + [200.0] * 3)) == []


def test_clock_jumping_back_is_a_gap_but_jitter_and_stuck_stamps_are_not():
    back = stamps([100.0] * 5 + [-5000.0] + [100.0] * 5)
    assert frames_after_gaps(back) == [6]
    jitter = stamps([100.0] * 5 + [150.0, -30.0, 150.0] + [100.0] * 5)
    assert frames_after_gaps(jitter) == []
    assert frames_after_gaps([5 * MS] * 20) == []


def test_a_gap_in_the_first_steps_or_right_after_another_is_found():
    assert frames_after_gaps(stamps([10_000.0] + [100.0] * 10)) == [1]
    assert frames_after_gaps(stamps([100.0] * (MIN_STEPS - 1) + [5000.0] + [100.0] * 5)) == [3]
    steps = [100.0] * 10 + [10_000.0, 100.0, 10_000.0] + [100.0] * 10
    assert frames_after_gaps(stamps(steps)) == [11, 13]
    back = [100.0] * 10 + [10_000.0, 100.0, -20_000.0] + [100.0] * 10
    assert frames_after_gaps(stamps(back)) == [11, 13]


def test_a_changed_rate_is_learnt_within_rate_steps():
    from lidarflow.stamps import RATE_STEPS

    # 20 Hz then 5 Hz: the first slower steps are gaps, not every one from then on
    assert frames_after_gaps(stamps([50.0] * 60 + [200.0] * 60)) == list(range(61, 66))
    assert RATE_STEPS == 5 and HISTORY // 2 > RATE_STEPS  # (a median alone: half the history)


def test_bad_threshold_is_refused():
    with pytest.raises(ValueError, match="max_gap_periods"):
        frames_after_gaps([0, 1, 2], 1.0)


@given(
    period=st.floats(20.0, 300.0),
    jitter=st.floats(0.0, 0.3),
    gap_periods=st.floats(3.0, 100.0),
    at=st.integers(MIN_STEPS + 2, 30),
)
def test_one_gap_in_a_jittery_stream_is_found_exactly(period, jitter, gap_periods, at):
    rng = np.random.default_rng(0)
    steps = list(period * (1 + jitter * rng.uniform(-1, 1, 40)))
    steps[at - 1] = gap_periods * period * (1 + jitter)  # longer than 2.5 jittered periods
    assert frames_after_gaps(stamps(steps)) == [at]


def test_the_stream_clock_paces_the_frames_after_gaps_as_the_recording_rule():
    from lidarflow.motion.pacing import StepClock, paced_motion, paces_after_long_steps

    # a gap, jitter, a scan dropped, a jump back
    steps = [100.0] * 8 + [700.0] + [100.0] * 3 + [140.0, 200.0] + [100.0] * 2 + [-50.0, 100.0]
    stamped = stamps(steps)
    offline = paces_after_long_steps(stamped)
    assert offline == {9: pytest.approx(100 / 700), 14: pytest.approx(0.5)}
    assert frames_after_gaps(stamped) == [9]  # only the gap is a gap
    clock = StepClock()
    online = {i: p for i, s in enumerate(stamped) if (p := clock.update(s)) is not None}
    assert online == offline
    # a scan without a stamp in between is passed over, not a jump to 1970 and back
    clock = StepClock()
    paces = [clock.update(s) for s in [*stamped[:5], 0, *stamped[5:8]]]
    assert paces == [None] * 9
    assert paced_motion(np.array([7.0, 0.0, 0.7]), 100 / 700) == pytest.approx([1.0, 0.0, 0.1])
    assert paced_motion(None, 0.5) is None and paced_motion(np.zeros(3), None) is None


def test_a_stream_that_slows_down_is_paced_until_five_steps_agree_on_its_rate():
    from lidarflow.motion.pacing import StepClock, paces_after_long_steps

    # 10 Hz, then 5 Hz: its first five steps may be scans dropped; from then on, the new rate
    stamped = stamps([100.0] * 10 + [200.0] * 40)
    offline = paces_after_long_steps(stamped)
    assert offline == {i: pytest.approx(0.5) for i in range(11, 16)}
    clock = StepClock()
    assert {i: p for i, s in enumerate(stamped) if (p := clock.update(s)) is not None} == offline
    # three scans dropped in a row are three paced steps, and no new rate
    stamped = stamps([100.0] * 10 + [200.0] * 3 + [100.0] * 3 + [200.0] + [100.0] * 3)
    assert sorted(paces_after_long_steps(stamped)) == [11, 12, 13, 17]


def test_a_new_rate_is_learnt_once_five_steps_agree_on_it():
    from lidarflow.motion.pacing import StepClock, paces_after_long_steps

    # 10 Hz, then 3.3 Hz: five gaps, then the new rate is the typical step
    assert frames_after_gaps(stamps([100.0] * 20 + [300.0] * 40)) == [21, 22, 23, 24, 25]
    # 3.3 Hz, then 10 Hz, then a scan dropped at the new rate: a long step at the new rate
    stamped = stamps([300.0] * 30 + [100.0] * 20 + [200.0] + [100.0] * 5)
    offline = paces_after_long_steps(stamped)
    assert offline == {51: pytest.approx(0.5)}
    clock = StepClock()
    assert {i: p for i, s in enumerate(stamped) if (p := clock.update(s)) is not None} == offline
    # jitter within a quarter, or one long step between typical ones, is no new rate
    jittery = stamps([100.0, 80.0, 120.0] * 10 + [300.0, 100.0, 100.0, 100.0])
    assert frames_after_gaps(jittery) == [31]
    # five long steps that do not agree on one length are dropped scans, not a new rate: the
    # typical step stays, and a scan dropped after them is paced again
    uneven = stamps([100.0] * 20 + [200.0, 300.0, 200.0, 400.0, 200.0] + [100.0] * 3 + [200.0])
    assert sorted(paces_after_long_steps(uneven)) == [21, 22, 23, 24, 25, 29]


def test_a_new_rate_is_learnt_through_jittery_stamps():
    from lidarflow.motion.pacing import paces_after_long_steps

    # 10 Hz then 5 Hz, stamps jittering by 20 % (Gaussian), 20 streams: paced for some steps after
    # the change, then the new rate is learnt; the median stream within 15 steps (comparing the
    # extremes of the last five instead of their median: 25)
    learnt = []
    for seed in range(20):
        rng = np.random.default_rng(seed)
        jitter = 1 + 0.2 * rng.standard_normal(140)
        steps = np.r_[np.full(60, 100.0), np.full(80, 200.0)] * np.clip(jitter, 0.3, None)
        paced = [i for i in paces_after_long_steps(stamps(list(steps))) if i > 60]
        learnt.append(max(paced, default=60) - 60)
    assert np.median(learnt) <= 15


def test_the_stream_step_is_the_last_step_until_the_typical_one_is_known():
    from lidarflow.motion.pacing import StepClock

    clock = StepClock()
    assert clock.step_ns is None
    stamped = stamps([120.0] + [100.0] * 12 + [700.0])
    clock.update(stamped[0])
    assert clock.step_ns is None  # one stamp: no step yet
    clock.update(stamped[1])
    assert clock.step_ns == 120 * MS  # the last step until the typical one is known
    for s in stamped[2:-1]:
        clock.update(s)
    assert clock.step_ns == 100 * MS
    clock.update(stamped[-1])  # a gap does not move the typical step
    assert clock.step_ns == 100 * MS
    clock.reset()
    assert clock.step_ns is None
