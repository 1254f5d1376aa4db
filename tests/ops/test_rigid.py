"""Tests of the rigid (ego-motion) warp: identity, exact integer translations, rotation round
trips, the sign convention against the simulator's ground-truth flow, bad input, gradients."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from lidarflow.ops.rigid import rigid_flow, rigid_warp, transform_cells


def _maps(seed: int, shape=(2, 3, 12, 10), dtype=torch.float32) -> torch.Tensor:
    return torch.rand(shape, generator=torch.Generator().manual_seed(seed), dtype=dtype)


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 10_000), h=st.integers(2, 12), w=st.integers(2, 12))
def test_identity_motion_leaves_maps_unchanged(seed, h, w):
    maps = _maps(seed, (2, 2, h, w))
    out = rigid_warp(maps, torch.zeros(2, 3))
    torch.testing.assert_close(out, maps, atol=1e-6, rtol=0)


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 10_000), fwd=st.integers(-4, 4), left=st.integers(-4, 4))
def test_integer_cell_translation_moves_cells_exactly(seed, fwd, left):
    res = 0.1
    maps = _maps(seed, (1, 1, 11, 10))
    out = rigid_warp(maps, torch.tensor([[fwd * res, left * res, 0.0]]), res=res)
    # Driving forward brings things closer (larger row); moving left moves them right.
    expected = torch.zeros_like(maps)
    h, w = maps.shape[-2:]
    for r in range(h):
        for c in range(w):
            r0, c0 = r - fwd, c - left
            if 0 <= r0 < h and 0 <= c0 < w:
                expected[..., r, c] = maps[..., r0, c0]
    torch.testing.assert_close(out, expected, atol=1e-5, rtol=0)


def test_quarter_turn_left_brings_the_left_side_ahead():
    # 20 x 20 grid, sensor at the bottom middle (between columns 9 and 10, below row 19).
    maps = torch.zeros(1, 1, 20, 20)
    maps[0, 0, 19, 0] = 1.0  # a point 0.5 cells ahead and 9.5 cells to the left
    out = rigid_warp(maps, torch.tensor([[0.0, 0.0, math.pi / 2]]))
    # After turning 90 degrees left the point is 9.5 cells ahead, 0.5 cells to the right.
    r, c = divmod(int(out.flatten().argmax()), 20)
    assert (r, c) == (10, 10)
    assert out.max().item() == pytest.approx(1.0, abs=1e-5)


@settings(max_examples=15, deadline=None)
@given(
    seed=st.integers(0, 1000), yaw=st.floats(-0.6, 0.6), dx=st.floats(-2, 2), dy=st.floats(-2, 2)
)
def test_transform_cells_inverse_round_trip(seed, yaw, dx, dy):
    g = torch.Generator().manual_seed(seed)
    cols, rows = torch.rand(1, 5, 7, generator=g) * 30, torch.rand(1, 5, 7, generator=g) * 30
    m = torch.tensor([[dx, dy, yaw]], dtype=torch.float32)
    c2, r2 = transform_cells(cols, rows, m, 30, 30)
    c3, r3 = transform_cells(c2, r2, m, 30, 30, inverse=True)
    torch.testing.assert_close(c3, cols, atol=1e-4, rtol=0)
    torch.testing.assert_close(r3, rows, atol=1e-4, rtol=0)


def test_rotate_then_back_is_identity_on_the_interior():
    # A smooth map so that two bilinear resamplings lose little.
    h = w = 40
    rr, cc = torch.meshgrid(torch.arange(h), torch.arange(w), indexing="ij")
    maps = (torch.sin(rr / 4.0) * torch.cos(cc / 5.0))[None, None].float()
    a = 0.3
    there = rigid_warp(maps, torch.tensor([[0.0, 0.0, a]]))
    back = rigid_warp(there, torch.tensor([[0.0, 0.0, -a]]))
    # the interior near the sensor stays in view under both turns
    inner = (slice(25, 38), slice(14, 26))
    err = (back[0, 0][inner] - maps[0, 0][inner]).abs().max().item()
    assert err < 0.05


def test_fill_value_enters_from_outside_and_bad_input_is_rejected():
    maps = torch.zeros(1, 1, 6, 6)
    out = rigid_warp(maps, torch.tensor([[-3.0, 0.0, 0.0]]), fill=-4.0)  # backing away
    assert torch.all(out[0, 0, 3:] == -4.0) and torch.all(out[0, 0, :2] == 0.0)
    with pytest.raises(ValueError, match=r"motion must be \(B, 3\)"):
        rigid_warp(maps, torch.zeros(1, 2))
    with pytest.raises(ValueError, match="rows for a batch"):
        rigid_warp(maps, torch.zeros(2, 3))
    with pytest.raises(ValueError, match=r"maps must be \(B, C, H, W\)"):
        rigid_warp(maps[0], torch.zeros(1, 3))


def test_gradcheck_float64_in_maps_and_motion():
    maps = _maps(1, (1, 2, 6, 5), torch.float64).requires_grad_()
    motion = torch.tensor([[0.37, -0.21, 0.13]], dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda m, x: rigid_warp(m, x), (maps, motion))


def test_rigid_flow_matches_the_simulators_ground_truth_on_static_structure():
    """The convention end to end: for static structure the simulator's exact backward flow B^t
    is the sensor's own motion t -> t+1, i.e. rigid_flow(relative(pose_t, pose_t+1))."""
    from lidarflow.motion.odometry import metres_to_cells, relative_motions
    from lidarflow.scan import GridSpec
    from lidarflow.sim import PeopleConfig, SimConfig, dense_flow, simulate

    grid = GridSpec(60, 60, 0.1)
    cfg = SimConfig(scenario="dynamic", episode_frames=40, grid=grid, people=PeopleConfig(count=0))
    rec = simulate(30, seed=5, config=cfg)
    motions, _ = relative_motions(rec.extras["true_poses"])
    occ, _ = rec.maps(grid)
    errors, moved = [], 0.0
    for t in range(5, 28):
        gt = dense_flow(rec, t)[0]  # B^t (2, H, W), defined on occupied cells of O^{t+1}
        m = torch.from_numpy(metres_to_cells(motions[t + 1][None], grid.res))
        est = rigid_flow(m, 60, 60)[0].numpy()
        cells = occ[t + 1]
        errors.append(np.hypot(*(est - gt))[cells])
        moved += float(np.abs(gt[:, cells]).mean())
    err = np.concatenate(errors)
    assert moved > 0.5  # the robot really drove
    assert np.median(err) < 0.05
