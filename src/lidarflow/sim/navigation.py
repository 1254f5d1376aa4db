"""Closed-loop navigation episodes: a robot that plans on its obstacle maps crosses a crowd.

A differential-drive robot in an open hall (:func:`open_hall`) with ``walkers`` social-force
people (who avoid it as one more agent) is sent to a goal. Every frame the LiDAR scans, the
obstacle source (:mod:`lidarflow.sim.obstacles`) makes maps ``1..K`` ahead, the
:class:`~lidarflow.sim.local_planner.LocalPlanner` picks a command, the people step, and the
robot drives under its acceleration limits (a move into an obstacle is refused).

It ends at the goal (within ``goal_tolerance``), on a **collision** (the robot's disc overlaps a
present person's body disc) or after ``max_time`` s. The scene depends only on
``(seed, walkers)``, so every source meets the same scenes. ``min_distance_m`` is the smallest
distance between the robot's centre and a present person's (NaN where nobody was there).
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field

import numpy as np

from lidarflow.errors import SimError
from lidarflow.scan import GridSpec, Scan, rasterize
from lidarflow.sim.lidar import STATIC_ID, LidarConfig, cast_rays, lidar_preset, measure
from lidarflow.sim.local_planner import LocalPlanner, PlannerConfig, RobotConfig
from lidarflow.sim.obstacles import ObstacleSource, Sensed
from lidarflow.sim.people import PeopleConfig
from lidarflow.sim.platform import drive
from lidarflow.sim.social import SocialCrowd
from lidarflow.sim.world import World, outline

__all__ = ["NavConfig", "Outcome", "open_hall", "run_episode", "scene"]


@dataclass(frozen=True)
class NavConfig:
    """One crowd size's episodes (SI units): the hall ``hall`` m, the goal ``goal_distance`` m
    from the start, maps ``horizon_s`` s ahead."""

    walkers: int = 8
    sensor: LidarConfig = field(default_factory=lambda: lidar_preset("tim561"))
    grid: GridSpec = field(default_factory=GridSpec)
    robot: RobotConfig = field(default_factory=RobotConfig)
    planner: PlannerConfig = field(default_factory=PlannerConfig)
    hall: tuple[float, float] = (12.0, 12.0)
    goal_distance: tuple[float, float] = (6.0, 10.0)
    horizon_s: float = 1.0
    max_time: float = 40.0
    goal_tolerance: float = 0.4

    def __post_init__(self) -> None:
        if self.walkers < 0 or self.max_time <= 0 or self.horizon_s <= 0:
            raise SimError(f"walkers >= 0, max_time > 0 and horizon_s > 0 please: {self}")

    @property
    def horizon(self) -> int:
        """Frames ahead the obstacle maps reach (at least one)."""
        return max(1, round(self.horizon_s * self.sensor.rate_hz))


@dataclass(frozen=True)
class Outcome:
    """How an episode ended: ``success`` (the goal reached without a collision), ``collision``,
    ``time_s`` (at the end), ``min_distance_m`` (module docstring) and the robot's ``path``
    ``(T, 3)`` of poses."""

    success: bool
    collision: bool
    time_s: float
    min_distance_m: float
    path: np.ndarray


def open_hall(width: float, height: float, walls: np.ndarray | None = None) -> World:
    """A single empty room ``width x height`` m (corner at the origin), with extra ``walls``
    ``(N, 4)`` segments ``(x0, y0, x1, y1)`` that the LiDAR sees and everyone avoids."""
    extra = np.zeros((0, 4)) if walls is None else np.asarray(walls, np.float64).reshape(-1, 4)
    segments = np.concatenate([np.array(outline(width, height), np.float64), extra])
    return World(
        segments=segments,
        circles=np.zeros((0, 3)),
        avoid_segments=segments.copy(),
        avoid_circles=np.zeros((0, 3)),
        rooms=np.array([[0.0, 0.0, width, height]]),
        corridor=np.array([False]),
        doors=[],
        reachable=np.array([True]),
        bounds=(0.0, 0.0, width, height),
    )


def scene(config: NavConfig, seed: int) -> tuple[World, np.ndarray, np.ndarray]:
    """The hall, the start pose ``(x, y, yaw)`` (facing the goal) and the goal ``(x, y)`` of
    episode ``seed``: points at least 1 m from the walls, ``goal_distance`` apart."""
    world = open_hall(*config.hall)
    rng = np.random.default_rng([seed, config.walkers, 1])
    lo, hi = config.goal_distance
    for _ in range(200):
        start, goal = world.sample_free(rng, clearance=1.0), world.sample_free(rng, clearance=1.0)
        if start is not None and goal is not None and lo <= math.dist(start, goal) <= hi:
            yaw = math.atan2(goal[1] - start[1], goal[0] - start[0])
            return world, np.array([start[0], start[1], yaw]), goal
    raise SimError(f"no start and goal {lo}-{hi} m apart fit a {config.hall} m hall")


def _crowd(world: World, config: NavConfig, pose: np.ndarray, seed: int) -> SocialCrowd:
    """The people, none of them within 1.5 m of the robot at the start."""
    rng = np.random.default_rng([seed, config.walkers, 2])
    sensor = config.sensor
    crowd = SocialCrowd(
        world, PeopleConfig(count=config.walkers), rng, pose, math.radians(sensor.fov_deg),
        sensor.range_max,
    )  # fmt: skip
    for i in np.flatnonzero(crowd.walking()):
        for _ in range(20):
            if math.dist(crowd.pos[i], pose[:2]) >= 1.5:
                break
            spot = world.sample_free(rng)
            if spot is not None:
                crowd.pos[i] = crowd.check_pos[i] = spot
    return crowd


def _future_legs(crowd: SocialCrowd, pose: np.ndarray, config: NavConfig) -> np.ndarray:
    """``(K, L, 3)`` the legs ``1..K`` frames on, the people stepped on a copy (its own
    generator state too) with the robot where it is now."""
    ahead = copy.deepcopy(crowd, memo={id(crowd.world): crowd.world})
    dt = 1.0 / config.sensor.rate_hz
    out = []
    for _ in range(config.horizon):
        ahead.step(dt, pose, config.robot.radius)
        out.append(ahead.legs())
    return np.stack(out)


def _sense(
    world: World, crowd: SocialCrowd, pose: np.ndarray, config: NavConfig, frame: int,
    rng: np.random.Generator,
) -> tuple[Scan, np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """The scan at ``pose``, its maps and its cells hit on walls and furniture."""
    legs = crowd.legs()
    legs = legs[~np.isnan(legs[:, 0])]
    circles = np.concatenate([world.circles, legs])
    ids = np.concatenate(
        [np.full(len(world.circles), STATIC_ID, np.int32), np.arange(len(legs), dtype=np.int32)]
    )
    geom = config.sensor.geometry()
    true, hit = cast_rays(pose[None], geom, world.segments, circles, ids)
    ranges = measure(true, config.sensor, rng)[0].astype(np.float32)
    stamp = round((frame + 1) * 1e9 / config.sensor.rate_hz)
    scan = Scan(ranges, geom, stamp)
    occupancy, visibility = rasterize(scan, config.grid)
    walls = Scan(np.where(hit[0] == STATIC_ID, ranges, np.inf).astype(np.float32), geom, stamp)
    return scan, occupancy, visibility, rasterize(walls, config.grid)[0]


def run_episode(
    source: ObstacleSource,
    seed: int,
    config: NavConfig | None = None,
    world: World | None = None,
    start: np.ndarray | None = None,
    goal: np.ndarray | None = None,
) -> Outcome:
    """Run episode ``seed`` with the planner on ``source``'s maps (of ``config.horizon``
    frames); ``world``, ``start`` ``(x, y, yaw)`` and ``goal`` ``(x, y)`` replace the scene's."""
    config = config or NavConfig()
    if source.horizon != config.horizon:
        raise SimError(f"the source's horizon {source.horizon} is not {config.horizon} frames")
    hall, first, aim = scene(config, seed)
    world = hall if world is None else world
    pose = np.array(first if start is None else start, np.float64)
    goal = np.asarray(aim if goal is None else goal, np.float64)
    crowd = _crowd(world, config, pose, seed)
    noise = np.random.default_rng([seed, config.walkers, 3])
    dt = 1.0 / config.sensor.rate_hz
    planner = LocalPlanner(config.grid, dt, config.robot, config.planner)
    touch = config.robot.radius + crowd.cfg.body_radius
    vw, path, nearest = np.zeros(2), [pose.copy()], math.inf
    frames = math.ceil(config.max_time * config.sensor.rate_hz)
    for t in range(frames):
        scan, occupancy, visibility, static = _sense(world, crowd, pose, config, t, noise)
        future = _future_legs(crowd, pose, config) if source.wants_future else None
        sensed = Sensed(scan, pose.copy(), occupancy, visibility, static, future)
        c, s = math.cos(pose[2]), math.sin(pose[2])
        d = goal - pose[:2]
        target = planner.command(
            source.maps(sensed), np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1]]), *vw
        )
        crowd.step(dt, pose, config.robot.radius)
        pose = drive(world, pose, vw, target, config.robot, dt)
        path.append(pose.copy())
        people = crowd.pos[crowd.walking()]
        if len(people):
            nearest = min(nearest, float(np.hypot(*(people - pose[:2]).T).min()))
        elapsed = (t + 1) * dt
        if nearest < touch:
            return Outcome(False, True, elapsed, nearest, np.array(path))
        if math.dist(pose[:2], goal) <= config.goal_tolerance:
            return Outcome(True, False, elapsed, _finite(nearest), np.array(path))
    return Outcome(False, False, frames * dt, _finite(nearest), np.array(path))


def _finite(distance: float) -> float:
    return distance if math.isfinite(distance) else math.nan
