"""Closed-loop navigation: the planner crosses empty halls and avoids walls; every obstacle
source gives maps of the grid's shape."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lidarflow.errors import SimError
from lidarflow.scan import GridSpec
from lidarflow.sim.local_planner import LocalPlanner, RobotConfig, rollouts
from lidarflow.sim.navigation import NavConfig, open_hall, run_episode
from lidarflow.sim.obstacles import SOURCES, Sensed, make_source


def test_rollouts_respect_the_acceleration_limits():
    robot = RobotConfig()
    paths = rollouts(0.0, 0.0, np.array([[1.0, 0.0]]), robot, 0.1, 5)
    # from rest at 1 m/s^2: 0.1, 0.2, ... m/s, so x = 0.01 + 0.02 + ... after each step
    assert np.allclose(paths[0, :, 0], np.cumsum(0.01 * np.arange(1, 6)))
    assert np.allclose(paths[0, :, 1:], 0.0)


def test_planner_heads_for_a_clear_goal_and_turns_from_a_wall_ahead():
    grid = GridSpec(40, 40, 0.1)
    planner = LocalPlanner(grid, 1 / 15)
    free = np.zeros((15, *grid.shape), np.float32)
    v, w = planner.command(free, np.array([3.0, 0.0]), 0.5, 0.0)
    assert v == 1.0 and w == 0.0
    wall = free.copy()
    wall[:, 30:33, 10:30] = 1.0  # 0.7-1.0 m ahead, 1 m wide across the way
    v, w = planner.command(wall, np.array([3.0, 0.0]), 1.0, 0.0)
    assert w != 0.0 or v < 1.0
    with pytest.raises(SimError, match="obstacle maps"):
        planner.command(np.zeros((10, 10)), np.array([3.0, 0.0]), 0.0, 0.0)


def test_an_empty_hall_is_crossed_without_collision():
    config = NavConfig(walkers=0)
    outcome = run_episode(make_source("last_scan", config.grid, config.horizon), 0, config)
    assert outcome.success and not outcome.collision
    assert math.isnan(outcome.min_distance_m)
    assert 5.0 < outcome.time_s < 20.0  # 6-10 m at up to 1 m/s


def test_a_wall_in_the_way_is_avoided():
    config = NavConfig(walkers=0)
    wall = np.array([[6.0, 4.0, 6.0, 8.0]])  # across the straight line from (3, 6) to (9, 6)
    world = open_hall(12.0, 12.0, wall)
    source = make_source("last_scan", config.grid, config.horizon)
    start, goal = np.array([3.0, 6.0, 0.0]), np.array([9.0, 6.0])
    outcome = run_episode(source, 0, config, world=world, start=start, goal=goal)
    assert outcome.success and not outcome.collision
    clearance = world.clearance(outcome.path[:, :2])
    assert clearance.min() >= config.robot.radius
    assert np.abs(outcome.path[:, 1] - 6.0).max() > 2.0  # went round an end of the wall


def test_every_source_gives_maps_of_the_grids_shape():
    from lidarflow.predict import Predictor

    grid, horizon = GridSpec(), 3
    config = NavConfig(walkers=3, horizon_s=horizon / 15, max_time=0.4)
    predictor = Predictor(grid=grid, horizon=horizon)
    seen = {}
    for name in SOURCES:
        source = make_source(name, grid, horizon, predictor if name == "lidarflow" else None)
        maps = []
        original = source.maps

        def keep(sensed: Sensed, original=original, maps=maps) -> np.ndarray:
            maps.append(np.asarray(original(sensed)))
            return maps[-1]

        source.maps = keep  # type: ignore[method-assign]
        run_episode(source, 1, config)
        seen[name] = maps
    for name, maps in seen.items():
        assert len(maps) == 6, name  # 0.4 s at 15 Hz
        for m in maps:
            assert m.shape == (horizon, *grid.shape), name
            assert m.min() >= 0.0 and m.max() <= 1.0, name
        assert any(m.max() == 1.0 for m in maps), name  # the hall's walls at least


def test_sources_are_checked():
    grid = GridSpec()
    with pytest.raises(SimError, match="one of"):
        make_source("radar", grid, 3)
    with pytest.raises(SimError, match="Predictor"):
        make_source("lidarflow", grid, 3)
    with pytest.raises(SimError, match="horizon"):
        run_episode(make_source("last_scan", grid, 3), 0, NavConfig(walkers=0))
