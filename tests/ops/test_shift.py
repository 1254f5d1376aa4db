"""The torch constant-velocity extrapolation is the NumPy baseline's, map for map."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from lidarflow.evaluate.baselines import ConstantVelocity, best_rigid_shift, shift_map
from lidarflow.ops.shift import all_shifts, constant_velocity_map


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), dc=st.integers(-3, 3), dr=st.integers(-3, 3))
def test_all_shifts_match_the_numpy_shift(seed, dc, dr):
    image = np.random.default_rng(seed).random((9, 11)).astype(np.float32)
    shifts = all_shifts(torch.from_numpy(image)[None, None], radius=3)
    index = (dr + 3) * 7 + (dc + 3)
    np.testing.assert_array_equal(shifts[0, index].numpy(), shift_map(image, dc, dr))


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    dc=st.integers(-4, 4),
    dr=st.integers(-4, 4),
    density=st.floats(0.0, 0.6),
)
def test_constant_velocity_map_is_the_baselines_prediction(seed, dc, dr, density):
    # A scene moved by (dc, dr) plus noise: shifts beyond the radius and ties both occur.
    rng = np.random.default_rng(seed)
    previous = (rng.random((14, 12)) < density).astype(np.float32)
    current = shift_map(previous, dc, dr)
    current[rng.random(current.shape) < 0.1] = 1.0
    baseline = ConstantVelocity(radius=3)
    baseline.update(previous, np.ones_like(previous))
    expected = baseline.update(current, np.ones_like(current))
    got = constant_velocity_map(
        torch.from_numpy(previous)[None, None], torch.from_numpy(current)[None, None]
    )
    np.testing.assert_array_equal(got[0, 0].numpy(), expected)


def test_a_batch_picks_one_shift_per_map_and_a_blank_past_picks_none():
    scene = np.zeros((10, 10), dtype=np.float32)
    scene[4:6, 3] = 1.0
    moved = shift_map(scene, 2, -1)
    previous = torch.from_numpy(np.stack([scene, np.zeros_like(scene)]))[:, None]
    current = torch.from_numpy(np.stack([moved, moved]))[:, None]
    out = constant_velocity_map(previous, current)
    assert best_rigid_shift(scene, moved) == (2, -1)
    np.testing.assert_array_equal(out[0, 0].numpy(), shift_map(moved, 2, -1))
    np.testing.assert_array_equal(out[1, 0].numpy(), moved)  # first frame: copy-last


def test_mismatched_shapes_are_refused():
    with pytest.raises(ValueError, match="must match"):
        constant_velocity_map(torch.zeros(1, 1, 5, 5), torch.zeros(1, 1, 5, 6))
    with pytest.raises(ValueError, match=r"\(B, 1, H, W\)"):
        all_shifts(torch.zeros(1, 2, 5, 5), 1)
