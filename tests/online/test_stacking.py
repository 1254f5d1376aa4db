"""The stacked combination of one horizon: it starts as its prior expert, learns to trust the
expert that is right, and decides at thresholds that fall on the metric's 0.4."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from lidarflow.online import stacking
from lidarflow.online.stacking import (
    DECIDED,
    HorizonStacking,
    StackingConfig,
    best_thresholds,
    best_thresholds_each,
    rescaled,
)

SHAPE = (20, 20)


@given(
    st.floats(0.0, 1.0, allow_nan=False),
    st.floats(0.01, 0.99, allow_nan=False),
)
def test_rescaled_decides_at_its_threshold_what_the_probability_decides_there(p, threshold):
    q = float(rescaled(np.array(p), threshold))
    assert 0.0 <= q <= 1.0 + 1e-6
    assert (q >= DECIDED - 1e-6) == (p >= threshold) or abs(p - threshold) < 1e-6


def test_it_starts_as_its_prior_expert():
    rng = np.random.default_rng(0)
    experts = rng.random((3, *SHAPE))
    stack = HorizonStacking(3, prior=1)
    clip = stack.config.clip
    p, decided = stack.decided(experts, np.zeros(SHAPE, bool))
    np.testing.assert_allclose(p, np.clip(experts[1], clip, 1 - clip), atol=1e-9)
    np.testing.assert_array_equal(decided >= DECIDED, p >= DECIDED)


def test_it_learns_to_follow_the_expert_that_is_right():
    """Expert 0 (the prior) is noise, expert 1 says the truth: after a stream of pairs the
    combination decides as expert 1."""
    rng = np.random.default_rng(1)
    stack = HorizonStacking(2, prior=0)
    rare = rng.random(SHAPE) < 0.5
    for _ in range(150):
        truth = rng.random(SHAPE) < 0.2
        experts = np.stack([rng.random(SHAPE), np.where(truth, 0.9, 0.1)])
        stack.learn(experts, rare, truth)
    truth = rng.random(SHAPE) < 0.2
    experts = np.stack([rng.random(SHAPE), np.where(truth, 0.9, 0.1)])
    _, decided = stack.decided(experts, rare)
    assert np.array_equal(decided >= DECIDED, truth)
    assert stack.weights[3] > stack.weights[2]  # expert 1's weight above the prior's


def test_quiet_cells_are_counted_as_the_cells_they_stand_for():
    """Learning on a map where most cells are quiet (every expert under the clip) moves the
    weights as learning on every cell one by one would."""
    rng = np.random.default_rng(2)
    experts = np.where(rng.random((2, *SHAPE)) < 0.1, rng.random((2, *SHAPE)), 0.0)
    rare = rng.random(SHAPE) < 0.3
    truth = rng.random(SHAPE) < 0.05
    fast = HorizonStacking(2)
    fast.learn(experts, rare, truth)
    slow = HorizonStacking(2, StackingConfig(clip=0.02))
    # the same step computed on every cell as active: nudge every quiet cell just over the clip
    nudged = np.where(experts <= 0.02, 0.02 + 1e-12, experts)
    slow.learn(nudged, rare, truth)
    np.testing.assert_allclose(fast.weights, slow.weights, atol=1e-6)


def test_the_thresholds_maximise_the_f1s_they_are_chosen_by():
    bins = 10
    occupied = np.zeros((2, bins))
    free = np.zeros((2, bins))
    occupied[0, 7] = 100  # common cells: occupied ones at 0.7, free ones at 0.3
    free[0, 3] = 100
    occupied[1, 2] = 10  # rare cells: occupied at 0.2, free at 0.05
    free[1, 0] = 100
    common, rare = best_thresholds(occupied, free, 1.0)
    assert 0.3 < common <= 0.7 and 0.05 < rare <= 0.2
    np.testing.assert_array_equal(best_thresholds(np.zeros((2, 4)), np.ones((2, 4)), 1.0), DECIDED)


@pytest.mark.usefixtures("compile_now")
@pytest.mark.parametrize("compiled", [True, False])
def test_thresholds_chosen_together_are_each_chosen_alone(compiled, monkeypatch):
    """Several horizons' thresholds in one pass: each as :func:`best_thresholds` alone, also
    for counts with nothing occupied yet."""
    if not compiled:
        monkeypatch.setattr(stacking, "ready", lambda *args, **kwargs: False)
    rng = np.random.default_rng(4)
    occupied = rng.random((5, 2, 40)) * rng.integers(0, 3, (5, 2, 40))
    free = rng.random((5, 2, 40)) * 50
    occupied[3] = 0.0
    together = best_thresholds_each(occupied, free, 0.7)
    assert together.shape == (5, 2)
    for k in range(5):
        np.testing.assert_array_equal(together[k], best_thresholds(occupied[k], free[k], 0.7))
    np.testing.assert_array_equal(together[3], DECIDED)


def test_a_state_goes_back_and_a_wrong_one_is_refused():
    rng = np.random.default_rng(3)
    stack = HorizonStacking(2)
    stack.learn(rng.random((2, *SHAPE)), rng.random(SHAPE) < 0.5, rng.random(SHAPE) < 0.2)
    other = HorizonStacking(2)
    other.load_state(stack.state())
    assert all(
        np.array_equal(a, b)
        for a, b in zip(stack.state().values(), other.state().values(), strict=True)
    )
    with pytest.raises(ValueError, match="weights"):
        HorizonStacking(3).load_state(stack.state())


def test_a_bad_configuration_is_refused():
    with pytest.raises(ValueError):
        StackingConfig(clip=0.6)
    with pytest.raises(ValueError):
        HorizonStacking(2, prior=2)
