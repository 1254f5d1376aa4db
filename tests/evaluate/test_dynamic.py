"""The dynamic region's world grid in tiles (issue 51): the same counts as one grid over the
trajectory's bounding box, without its memory where the poses spread over kilometres or one
of them glitches far away."""

from __future__ import annotations

import json

import numpy as np
import pytest

from lidarflow.data.recording import Recording
from lidarflow.evaluate.dynamic import (
    TILE,
    WorldCells,
    dynamic_cells,
    frame_region,
    world_counts,
)
from lidarflow.motion.odometry import pose_jumps
from lidarflow.scan import BeamGeometry, GridSpec, Scan
from tests.memlimit import GIB, run_limited

GRID = GridSpec(30, 30, 0.1)


def _box_regions(grid, poses, occupancy, visibility):
    """Each frame's region counted in one grid over the poses' bounding box (the layout before
    the tiles), for reference."""
    h, w, res = grid.height, grid.width, grid.res
    rows, cols = np.mgrid[0:h, 0:w]
    x, y = (h - rows - 0.5) * res, (w / 2 - cols - 0.5) * res
    reach = float(np.hypot(h * res, w / 2 * res)) + 2 * res
    low = poses[:, :2].min(axis=0) - reach
    shape = np.ceil((poses[:, :2].max(axis=0) + reach - low) / res).astype(int)
    where = []
    for px, py, yaw in poses:
        c, s = np.cos(yaw), np.sin(yaw)
        i = np.floor((px + c * x - s * y - low[0]) / res).astype(np.int64)
        j = np.floor((py + s * x + c * y - low[1]) / res).astype(np.int64)
        where.append(i * shape[1] + j)
    occupied, seen = np.zeros(shape.prod(), int), np.zeros(shape.prod(), int)
    for t, cells in enumerate(where):
        occupied[np.unique(cells[occupancy[t]])] += 1
        seen[np.unique(cells[visibility[t] | occupancy[t]])] += 1
    dynamic = dynamic_cells(occupied, seen)
    return [dynamic[cells] for cells in where]


def test_the_tiles_count_as_one_grid_over_the_bounding_box_did():
    rng = np.random.default_rng(5)
    n = 80
    steps = rng.normal(0, 0.3, (n, 3)) * [1, 1, 0.3]
    poses = np.cumsum(steps, axis=0) + np.array([-7.3, 12.1, 0.4])  # crosses tiles
    occupancy = rng.random((n, *GRID.shape)) < 0.08
    visibility = rng.random((n, *GRID.shape)) < 0.9
    cells = WorldCells(GRID, poses, n)
    masks = lambda t: (occupancy[t], visibility[t] | occupancy[t])  # noqa: E731
    region = frame_region(dynamic_cells(*world_counts(masks, cells)), cells)
    expected = _box_regions(GRID, poses, occupancy, visibility)
    assert sum(int(e.sum()) for e in expected) > 50
    for t in range(n):
        np.testing.assert_array_equal(region(t), expected[t])


def test_a_glitch_kilometres_away_allocates_only_the_tiles_its_scans_cover():
    n = 20
    poses = np.zeros((n, 3))
    poses[:, 0] = np.arange(n) * 0.05
    poses[7, :2] = 3000.0  # one odometry glitch: a box of 30,000 x 30,000 cells
    cells = WorldCells(GridSpec(), poses, n)
    occupancy = np.ones((n, 100, 100), bool)
    counts = world_counts(lambda t: (occupancy[t],), cells)
    assert cells.size <= 20 * TILE * TILE
    assert len(counts[0]) == cells.size
    assert frame_region(counts[0] > 0, cells)(7).all()  # the glitched frame still has its cells


def test_poses_far_from_the_origin_count_without_an_index_error():
    n = 8
    poses = np.zeros((n, 3))
    poses[:, :2] = 1e16  # IndexError here before the tiles
    poses[:, 2] = np.linspace(0, 3, n)
    occupancy = np.ones((n, *GRID.shape), bool)
    cells = WorldCells(GRID, poses, n)
    held = world_counts(lambda t: (occupancy[t],), cells)
    # too far to place: as a recording without poses, counted in the sensor frame
    assert (cells(3) == np.arange(GRID.height * GRID.width).reshape(GRID.shape)).all()
    poses[:, :2] = 5e6  # a UTM northing: far, yet placed
    poses[5, :2] = 1e16  # one glitch out of reach: that frame's pose unknown
    cells = WorldCells(GRID, poses, n)
    held = world_counts(lambda t: (occupancy[t],), cells)
    region = frame_region(held[0] > 0, cells)
    assert region(3).all() and not region(5).any()


def test_pose_jumps_are_frames_moved_faster_than_a_robot_drives():
    stamps = np.arange(6) * 100_000_000
    poses = np.zeros((6, 3))
    poses[:, 0] = np.arange(6) * 0.1
    assert pose_jumps(poses, stamps) == []
    poses[3, :2] = [1000.0, 1000.0]
    poses[4] = np.nan
    assert [t for t, _ in pose_jumps(poses, stamps)] == [3, 5]  # there, and back
    assert pose_jumps(None, stamps) == []


def _recording_with_a_glitch(n: int, at: int, where: float) -> Recording:
    geometry = BeamGeometry(181, -np.pi / 2, np.pi / 180, 0.05, 8.0)
    ranges = np.full(181, 3.0, np.float32)
    ranges[::7] = 5.0
    scans = [Scan(ranges, geometry, 1_700_000_000 * 10**9 + t * 100_000_000) for t in range(n)]
    poses = np.zeros((n, 3))
    poses[:, 0] = np.arange(n) * 0.05
    poses[at, :2] = where
    return Recording.from_scans(scans, poses=poses, meta={"source": "glitch"})


@pytest.mark.slow
def test_evaluate_a_recording_whose_odometry_glitches_3_km_under_a_memory_limit(tmp_path):
    path = _recording_with_a_glitch(16, 9, 3000.0).save(tmp_path / "glitch.npz")
    done = run_limited(
        ["evaluate", str(path), "--baselines-only", "--warmup", "2", "-o", "r.json"],
        tmp_path, limit_bytes=2 * GIB,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    warnings = [line for line in done.stderr.splitlines() if "poses jump" in line]
    assert len(warnings) == 1 and "glitch.npz" in warnings[0], done.stderr
    assert "2 times" in warnings[0] and "before frame 9" in warnings[0]
    entry = json.loads((tmp_path / "r.json").read_text())["recordings"][0]
    assert entry["pose_jumps"] == 2
    assert entry["first_pose_jumps"][0]["before_frame"] == 9
