"""Ground-truth flow: exact on known motions, consistent with the rasterizer, warps maps."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from lidarflow.scan import GridSpec, cell_centres, rasterize_batch
from lidarflow.sim import PeopleConfig, SimConfig, simulate
from lidarflow.sim.groundtruth import ground_truth
from lidarflow.sim.lidar import cast_rays, lidar_preset

GRID = GridSpec(100, 100, 0.1)
# A room 12 m x 12 m around the sensor, with a pillar, so most of the map has returns.
ROOM = np.array(
    [
        [-2.0, -6.0, 10.0, -6.0],
        [10.0, -6.0, 10.0, 6.0],
        [10.0, 6.0, -2.0, 6.0],
        [-2.0, 6.0, -2.0, -6.0],
        [4.0, 1.0, 5.0, 2.0],
    ]
)


def warp(maps: torch.Tensor, flow: torch.Tensor) -> torch.Tensor:
    """W(I, f)(p) = bilinear sample of I at p + f(p), design notes section 3 (channel 0 column)."""
    height, width = maps.shape[-2:]
    rows, cols = torch.meshgrid(
        torch.arange(height, dtype=flow.dtype), torch.arange(width, dtype=flow.dtype), indexing="ij"
    )
    x = 2 * (cols + flow[:, 0]) / (width - 1) - 1
    y = 2 * (rows + flow[:, 1]) / (height - 1) - 1
    grid = torch.stack([x, y], dim=-1)
    return F.grid_sample(
        maps[:, None], grid, mode="bilinear", padding_mode="zeros", align_corners=True
    )[:, 0]


def test_warp_helper_follows_the_convention():
    maps = torch.zeros(1, 5, 5, dtype=torch.float64)
    maps[0, 1, 3] = 1.0  # row 1, column 3
    flow = torch.zeros(1, 2, 5, 5, dtype=torch.float64)
    flow[0, 0, 1, 2] = 1.0  # at (1, 2) look one column to the right
    assert warp(maps, flow)[0, 1, 2] == 1.0


def _two_frames(poses: np.ndarray):
    geom = lidar_preset("tim561").geometry()
    ranges, ids = cast_rays(poses, geom, ROOM)
    return ranges.astype(np.float32), ids, geom


def test_driving_forward_moves_everything_by_the_distance_driven():
    dx = 0.05  # half a cell
    poses = np.array([[0.0, 0.0, 0.0], [dx, 0.0, 0.0]])
    ranges, ids, geom = _two_frames(poses)
    bw, fw, moving = ground_truth(ranges, ids, poses, np.zeros((2, 0, 2)), geom, GRID)
    occ, _ = rasterize_batch(ranges, geom, GRID)
    # Static things come nearer: their row index grows by dx / res going forward in time.
    np.testing.assert_allclose(fw[0, 1][occ[0]], dx / GRID.res, atol=1e-6)
    np.testing.assert_allclose(fw[0, 0][occ[0]], 0.0, atol=1e-6)
    np.testing.assert_allclose(bw[0, 1][occ[1]], -dx / GRID.res, atol=1e-6)
    np.testing.assert_allclose(bw[0, 0][occ[1]], 0.0, atol=1e-6)
    assert not moving.any()  # the robot moves, the world does not


def test_turning_matches_the_rigid_motion_at_cell_centres_and_lives_on_occupied_cells():
    dyaw = 0.05
    poses = np.array([[0.0, 0.0, 0.0], [0.3, -0.1, dyaw]])
    ranges, ids, geom = _two_frames(poses)
    bw, fw, _ = ground_truth(ranges, ids, poses, np.zeros((2, 0, 2)), geom, GRID)
    occ, _ = rasterize_batch(ranges, geom, GRID)
    # Support: exactly the occupied cells of O^t (forward) and O^{t+1} (backward).
    np.testing.assert_array_equal(np.hypot(*fw[0]) > 0, occ[0])
    np.testing.assert_array_equal(np.hypot(*bw[0]) > 0, occ[1])
    # Value: a static point at p (frame t) is at R(-dyaw) (p - t) in frame t + 1.
    x, y = cell_centres(GRID)
    c, s = math.cos(dyaw), math.sin(dyaw)
    qx = c * (x - 0.3) + s * (y + 0.1)
    qy = -s * (x - 0.3) + c * (y + 0.1)
    expect_col, expect_row = -(qy - y) / GRID.res, -(qx - x) / GRID.res
    np.testing.assert_allclose(fw[0, 0][occ[0]], expect_col[occ[0]], atol=0.06)
    np.testing.assert_allclose(fw[0, 1][occ[0]], expect_row[occ[0]], atol=0.06)


def test_a_moving_leg_carries_its_own_motion():
    geom = lidar_preset("tim561").geometry()
    poses = np.zeros((2, 3))
    legs = np.array([[[3.0, 0.0]], [[3.0, 0.12]]])  # one leg stepping 0.12 m to the left
    circles = np.concatenate([legs, np.full((2, 1, 1), 0.07)], axis=2)
    ranges, ids = cast_rays(poses, geom, ROOM, circles, np.array([0]))
    ranges = ranges.astype(np.float32)
    bw, fw, moving = ground_truth(ranges, ids, poses, legs, geom, GRID)
    occ, _ = rasterize_batch(ranges, geom, GRID)
    leg_cells = moving[0]
    assert leg_cells.any() and (leg_cells <= occ[0]).all()
    # 0.12 m to the left is 1.2 columns towards column 0; static cells keep zero flow.
    np.testing.assert_allclose(fw[0, 0][leg_cells], -1.2, atol=1e-4)
    np.testing.assert_allclose(fw[0, 1][leg_cells], 0.0, atol=1e-4)
    assert np.abs(fw[0][:, occ[0] & ~leg_cells]).max() == 0
    assert np.abs(bw[0, 0][occ[1]]).max() == pytest.approx(1.2, abs=1e-4)


def _overlap(pred: torch.Tensor, cells: torch.Tensor) -> float:
    return float((pred[cells] > 0.2).double().mean())


@pytest.mark.parametrize("scenario", ["static", "dynamic"])
def test_backward_flow_warps_each_map_onto_the_next(scenario):
    # Mixed pixels flicker at random between frames, which no flow can predict: leave them out.
    sensor = lidar_preset("tim561", mixed_pixel_prob=0.0)
    config = SimConfig(
        scenario=scenario, sensor=sensor, people=PeopleConfig(count=10), episode_frames=200
    )
    rec = simulate(200, seed=2, config=config)
    occ, _ = rec.maps(GRID)
    maps = torch.tensor(occ, dtype=torch.float64)
    backward = torch.tensor(rec.extras["flow_backward"][:-1].astype(np.float64))
    forward = torch.tensor(rec.extras["flow_forward"][:-1].astype(np.float64))
    moving_next = torch.tensor(rec.extras["moving"][1:] & occ[1:])
    moving_now = torch.tensor(rec.extras["moving"][:-1] & occ[:-1])
    assert moving_next.sum() > 100  # enough walking people in view to mean something
    predicted = warp(maps[:-1], backward)
    gt, copy = _overlap(predicted, moving_next), _overlap(maps[:-1], moving_next)
    assert gt > 0.8 and gt > copy + 0.2
    back = warp(maps[1:], forward)
    gt, copy = _overlap(back, moving_now), _overlap(maps[1:], moving_now)
    assert gt > 0.8 and gt > copy + 0.2


def test_static_platform_without_people_gives_zero_flow():
    config = SimConfig(scenario="static", people=PeopleConfig(count=0), episode_frames=50)
    rec = simulate(50, seed=5, config=config)
    assert not rec.extras["flow_backward"].any()
    assert not rec.extras["flow_forward"].any()
    assert not rec.extras["moving"].any()
    assert rec.maps(GRID)[0].any()
