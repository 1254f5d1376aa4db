"""Motion from the scans (correlative scan matching): it recovers a drive's motion where the
world stands still, finds none where the sensor stands still, and uses rigid.py's convention."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lidarflow.motion.odometry import metres_to_cells, relative_motions
from lidarflow.motion.scanmatch import ScanOdometry, match_maps, scan_motions
from lidarflow.ops.rigid import rigid_warp
from lidarflow.scan import GridSpec
from lidarflow.sim import SimConfig, simulate


def _walls() -> np.ndarray:
    world = np.zeros((100, 100), bool)
    world[20, 10:90] = world[20:80, 15] = world[50:70, 70] = world[85, 40:60] = True
    return world


@pytest.mark.parametrize("motion", [(2.0, -1.0, 0.0), (1.3, 0.6, 0.03), (-3.0, 2.4, -0.05)])
def test_a_rigid_motion_of_the_whole_world_is_recovered_in_rigid_py_convention(motion):
    previous = _walls()
    m = torch.tensor([motion], dtype=torch.float32)
    current = rigid_warp(torch.from_numpy(previous.astype(np.float32))[None, None], m)[0, 0] > 0.5
    found = match_maps(previous, current.numpy())
    assert found is not None
    np.testing.assert_allclose(found[:2], motion[:2], atol=0.35)
    assert abs(found[2] - motion[2]) < np.deg2rad(0.5)


def test_the_same_map_twice_and_empty_maps_give_no_motion():
    walls = _walls()
    assert match_maps(walls, walls) is None
    assert match_maps(np.zeros_like(walls), walls) is None
    with pytest.raises(ValueError, match="two"):
        match_maps(walls, walls[:50])
    odometry = ScanOdometry()
    assert odometry.update(walls) is None and odometry.update(walls) is None


def test_a_simulated_drive_is_matched_close_to_its_true_odometry():
    grid = GridSpec(64, 64, 0.1)
    rec = simulate(80, seed=5, config=SimConfig(scenario="dynamic", episode_frames=100, grid=grid))
    occupancy = rec.maps(grid)[0]
    found = scan_motions(occupancy)
    true = metres_to_cells(relative_motions(rec.poses)[0], grid.res)
    matched = np.isfinite(found[:, 0])
    assert not matched[0] and matched.sum() >= 40
    error = np.abs(found[matched] - true[matched])
    assert np.median(error[:, :2]) < 0.3 and np.median(error[:, 2]) < np.deg2rad(0.5)
