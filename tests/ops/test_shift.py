"""The torch constant-velocity extrapolation is the NumPy baseline's, map for map."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from lidarflow.baselines import ConstantVelocity, best_rigid_shift, shift_map
from lidarflow.ops.shift import apply_shift, best_shift_kernel, shift_scores


def constant_velocity_map(previous: torch.Tensor, current: torch.Tensor) -> torch.Tensor:
    """The constant-velocity prediction from the torch shift kernels (as training builds it)."""
    return apply_shift(current, best_shift_kernel(previous, current))


def _torch(*maps: np.ndarray) -> list[torch.Tensor]:
    return [torch.from_numpy(m)[None, None] for m in maps]


def _scene(seed: int, dc: int, dr: int, density: float, shape=(14, 12)):
    """A scene moved by (dc, dr) plus noise: shifts beyond the radius and ties both occur."""
    rng = np.random.default_rng(seed)
    previous = (rng.random(shape) < density).astype(np.float32)
    current = shift_map(previous, dc, dr)
    current[rng.random(current.shape) < 0.1] = 1.0
    return previous, current


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    dc=st.integers(-4, 4),
    dr=st.integers(-4, 4),
    density=st.floats(0.0, 0.6),
)
def test_constant_velocity_map_is_the_baselines_prediction(seed, dc, dr, density):
    previous, current = _scene(seed, dc, dr, density)
    baseline = ConstantVelocity(radius=3)
    baseline.update(previous, np.ones_like(previous))
    expected = baseline.update(current, np.ones_like(current))
    got = constant_velocity_map(*_torch(previous, current))
    np.testing.assert_array_equal(got[0, 0].numpy(), expected)
    # The scores' first maximum is the baseline's shift, row-major over (d_row, d_col).
    d_col, d_row = best_rigid_shift(previous, current, radius=3)
    assert int(shift_scores(*_torch(previous, current)).argmax()) == (d_row + 3) * 7 + d_col + 3


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


def test_bf16_autocast_does_not_round_the_overlap_counts():
    # Overlap 401 at one row down, 400 at no shift: bf16 (8 significant bits) rounds 401 to
    # 400, and the tie rule would then pick no shift.
    previous, current = np.zeros((8, 420), np.float32), np.zeros((8, 420), np.float32)
    previous[3, :401] = 1.0
    current[4, :401] = 1.0
    current[3, :400] = 1.0
    assert best_rigid_shift(previous, current) == (0, 1)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        got = constant_velocity_map(*_torch(previous, current))
    assert got.dtype == torch.float32
    np.testing.assert_array_equal(got[0, 0].numpy(), shift_map(current, 0, 1))


def test_bad_shapes_are_refused():
    with pytest.raises(ValueError, match="must match"):
        constant_velocity_map(torch.zeros(1, 1, 5, 5), torch.zeros(1, 1, 5, 6))
    with pytest.raises(ValueError, match=r"\(B, 1, H, W\)"):
        constant_velocity_map(torch.zeros(1, 2, 5, 5), torch.zeros(1, 2, 5, 5))
