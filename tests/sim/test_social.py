"""Social-force walkers: the forces, a walker's path, determinism, and a simulated recording."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from lidarflow.errors import SimError
from lidarflow.scan import GridSpec
from lidarflow.sim import PeopleConfig, SimConfig, build_world, simulate
from lidarflow.sim.people import OFF, WALK
from lidarflow.sim.social import SocialConfig, SocialCrowd, pair_forces, wall_forces
from lidarflow.sim.world import World

CONFIG = SocialConfig()


def _push(distance: float) -> float:
    """The force from a standing person ``distance`` m ahead on one walking at them."""
    pos, vel, facing = np.zeros((1, 2)), np.zeros((1, 2)), np.array([[1.0, 0.0]])
    other = np.array([[distance, 0.0]])
    f = pair_forces(pos, vel, facing, other, np.zeros((1, 2)), np.array([0.25]), CONFIG, False)
    return float(f[0, 0])


def test_repulsion_points_away_and_decreases_with_distance():
    pushes = [_push(d) for d in (0.3, 0.5, 0.8, 1.2, 2.0)]
    assert all(p < 0 for p in pushes)  # away from the person ahead
    assert all(abs(a) > abs(b) for a, b in itertools.pairwise(pushes))


def test_people_behind_push_less_than_people_ahead():
    assert abs(_push(-0.8)) < abs(_push(0.8))


def test_walls_push_away_and_less_with_distance():
    away = np.array([[0.0, 1.0]] * 3)
    f = wall_forces(np.array([0.1, 0.3, 0.6]), away, CONFIG)
    assert np.all(f[:, 1] > 0) and f[0, 1] > f[1, 1] > f[2, 1]


def _room() -> World:
    """One empty 12 x 6 m room."""
    walls = np.array([[0, 0, 12, 0], [12, 0, 12, 6], [12, 6, 0, 6], [0, 6, 0, 0]], float)
    return World(
        walls, np.zeros((0, 3)), walls, np.zeros((0, 3)), np.array([[0.0, 0.0, 12.0, 6.0]]),
        np.array([False]), [], np.array([True]), (0.0, 0.0, 12.0, 6.0),
    )  # fmt: skip


def _crowd(starts, goals, speed: float = 1.0) -> SocialCrowd:
    world = _room()
    people = PeopleConfig(count=len(starts))
    social = SocialConfig(group_sizes=(1.0, 0.0, 0.0), speed_std=0.0, speed_mean=speed)
    far = np.array([100.0, 100.0, 0.0])  # the robot far away
    crowd = SocialCrowd(world, people, np.random.default_rng(0), far, math.pi, 1.0, social)
    crowd.speed0[:] = speed
    crowd.pos[:] = starts
    crowd.vel[:] = 0.0
    crowd.state[:] = WALK
    crowd.target[:] = goals
    crowd.final[:] = True
    return crowd


def _walk(crowd: SocialCrowd, seconds: float, dt: float = 0.1) -> np.ndarray:
    """Positions ``(T, P, 2)``, stepping the forces only (goals fixed)."""
    idx = np.arange(len(crowd.pos))
    out = []
    for _ in range(round(seconds / dt)):
        for _ in range(4):
            crowd.vel += dt / 4 * crowd._forces(idx, np.array([100.0, 100.0, 0.0]), 0.35)
            crowd.pos += dt / 4 * crowd.vel
        out.append(crowd.pos.copy())
    return np.array(out)


def test_lone_walker_reaches_its_goal_at_about_its_preferred_speed():
    path = _walk(_crowd([[1.0, 3.0]], [[11.0, 3.0]], speed=1.2), 12.0)
    speed = np.hypot(*np.diff(path[:, 0], axis=0).T) / 0.1
    assert np.linalg.norm(path[-1, 0] - [11.0, 3.0]) < 0.2
    assert np.median(speed[10:60]) == pytest.approx(1.2, abs=0.1)


def test_walkers_heading_at_each_other_do_not_collide():
    path = _walk(_crowd([[1.0, 3.0], [11.0, 3.1]], [[11.0, 3.0], [1.0, 3.1]]), 16.0)
    gap = np.hypot(*(path[:, 0] - path[:, 1]).T)
    assert gap.min() > 2 * 0.25 * 0.9  # bodies barely touch
    assert path[-1, 0, 0] > 10.0 and path[-1, 1, 0] < 2.0  # and both get by


def test_walker_does_not_enter_a_wall():
    path = _walk(_crowd([[6.0, 3.0]], [[6.0, 8.0]]), 8.0)  # a goal behind the wall at y = 6
    assert path[:, 0, 1].max() < 6.0 - 0.15


def test_groups_walk_together():
    world = build_world(np.random.default_rng(4))
    people = PeopleConfig(count=9)
    social = SocialConfig(group_sizes=(0.0, 0.0, 1.0))
    sensor = np.array([*world.sample_free(np.random.default_rng(1)), 0.0])
    crowd = SocialCrowd(world, people, np.random.default_rng(2), sensor, math.pi, 10.0, social)
    assert sorted(np.bincount(crowd.leader)[::3].tolist()) == [3, 3, 3]
    for _ in range(60):
        crowd.step(1 / 15, sensor)
        lead = crowd.leader
        on = crowd.state != OFF
        assert np.array_equal(on, on[lead])  # a group appears and leaves together
    here = crowd.state != OFF
    spread = np.hypot(*(crowd.pos - crowd.pos[crowd.leader]).T)[here]
    assert np.median(spread) < 1.5


def test_bad_config_is_refused():
    with pytest.raises(SimError, match="group_sizes"):
        SocialConfig(group_sizes=(0.5, 0.2, 0.2))
    with pytest.raises(SimError, match="walkers"):
        SimConfig(walkers="zombies")


SMALL = SimConfig(
    scenario="static", walkers="social", episode_frames=30, grid=GridSpec(40, 40, 0.1)
)


def test_same_seed_same_walk_and_it_differs_from_legacy():
    a, b = simulate(30, seed=5, config=SMALL), simulate(30, seed=5, config=SMALL)
    legacy = simulate(30, seed=5, config=SimConfig(**{**SMALL.__dict__, "walkers": "legacy"}))
    assert np.array_equal(a.ranges, b.ranges, equal_nan=True)
    assert np.array_equal(a.extras["flow_forward"], b.extras["flow_forward"])
    assert not np.array_equal(a.ranges, legacy.ranges, equal_nan=True)
    assert a.meta["sim_config"]["walkers"] == "social"


def test_simulate_command_writes_a_recording_with_social_walkers(tmp_path):
    from lidarflow.cli import main
    from lidarflow.data import load_recording

    out = tmp_path / "sim.npz"
    args = ["simulate", "-o", str(out), "-n", "20", "--grid", "40", "--walkers", "social"]
    with pytest.raises(SystemExit) as done:
        main(args)
    assert done.value.code == 0
    rec = load_recording(out)
    assert len(rec) == 20 and rec.meta["sim_config"]["walkers"] == "social"
