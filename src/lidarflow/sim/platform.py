"""The robot carrying the LiDAR: standing still, or driving smoothly through the floor plan.

A driving robot is a unicycle with acceleration limits that drives to random goals through doors,
pushed away from walls, furniture and people, slowing to turn and near people, pausing now and
then. Its pose is the sensor's ``(x, y, yaw)``. Odometry is the true pose, or with
``odom_drift > 0`` (roughly the relative error per metre driven) the true increments with a
per-episode scale error and random-walk noise integrated, drifting as wheel odometry does.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lidarflow.errors import SimError
from lidarflow.scan import BeamGeometry
from lidarflow.sim.lidar import cast_rays
from lidarflow.sim.local_planner import RobotConfig
from lidarflow.sim.world import World

__all__ = ["Platform", "PlatformConfig", "compose", "drive", "relative"]


#: The most odometry error per metre driven: at 1 the poses are off by as much as the robot
#: moved, which no wheel odometry is; beyond it they say nothing at all.
MAX_ODOM_DRIFT = 1.0


@dataclass(frozen=True)
class PlatformConfig:
    """The robot's motion limits and habits (SI units)."""

    moving: bool = True
    max_speed: float = 1.0
    max_turn_rate: float = 1.0
    accel: float = 0.8
    turn_accel: float = 2.5
    cruise: tuple[float, float] = (0.4, 1.0)
    pause_prob: float = 0.35
    pause_time: tuple[float, float] = (0.5, 4.0)
    radius: float = 0.3
    odom_drift: float = 0.0

    def __post_init__(self) -> None:
        if self.max_speed <= 0 or self.max_turn_rate <= 0:
            raise SimError(f"platform limits must be positive: {self}")
        if not 0 <= self.odom_drift <= MAX_ODOM_DRIFT:
            raise SimError(
                f"odom_drift (--odom-drift) must be in [0, {MAX_ODOM_DRIFT:g}] metres of error "
                f"per metre driven, got {self.odom_drift:g}"
            )


def compose(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Pose ``a`` followed by the relative pose ``b`` (both ``(x, y, yaw)``)."""
    c, s = math.cos(a[2]), math.sin(a[2])
    yaw = math.remainder(a[2] + b[2], 2 * math.pi)
    return np.array([a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], yaw])


def relative(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The pose of ``b`` in the frame of ``a``."""
    c, s = math.cos(a[2]), math.sin(a[2])
    dx, dy = b[0] - a[0], b[1] - a[1]
    return np.array([c * dx + s * dy, -s * dx + c * dy, math.remainder(b[2] - a[2], 2 * math.pi)])


def drive(
    world: World,
    pose: np.ndarray,
    vw: np.ndarray,
    target: tuple[float, float],
    limits: PlatformConfig | RobotConfig,
    dt: float,
) -> np.ndarray:
    """The pose ``(x, y, yaw)`` after ``dt`` s of a unicycle (midpoint rule) whose speeds ``vw``
    ``(v, w)`` (updated in place) move towards ``target`` under ``limits``' accelerations. A
    move that takes the disc of ``limits.radius`` closer into an obstacle is refused: it turns
    on the spot and stops (a bumper)."""
    vw[0] += np.clip(target[0] - vw[0], -limits.accel * dt, limits.accel * dt)
    vw[1] += np.clip(target[1] - vw[1], -limits.turn_accel * dt, limits.turn_accel * dt)
    x, y, yaw = pose
    mid, step = yaw + vw[1] * dt / 2, vw[0] * dt
    turned = math.remainder(yaw + vw[1] * dt, 2 * math.pi)
    new = np.array([x + step * math.cos(mid), y + step * math.sin(mid), turned])
    clear_new, clear_now = world.clearance(np.stack([new[:2], pose[:2]]))
    if clear_new < limits.radius and clear_new < clear_now:
        new[:2] = pose[:2]
        vw[0] = 0.0
    return new


def _clamp(x: float, lo: float, hi: float) -> float:
    return lo if x < lo else hi if x > hi else x


def _open_heading(world: World, xy: np.ndarray) -> float:
    """The direction with the most free space around ``xy`` (a 72-beam look around)."""
    geom = BeamGeometry(72, -math.pi, 2 * math.pi / 72, 0.0, 12.0)
    ranges, _ = cast_rays(np.array([[xy[0], xy[1], 0.0]]), geom, world.segments, world.circles)
    r = np.minimum(ranges[0], 12.0)
    window = np.convolve(np.concatenate([r[-8:], r, r[:8]]), np.ones(17), "valid")
    return float(geom.angles[int(np.argmax(window))])


class Platform:
    """The robot in ``world``: ``pose`` (true) and ``odom`` (as odometry reports it)."""

    def __init__(self, world: World, config: PlatformConfig, rng: np.random.Generator) -> None:
        self.world, self.cfg, self.rng = world, config, rng
        start = None
        for _ in range(20):
            start = world.sample_free(rng, clearance=0.6)
            if start is not None:
                break
        if start is None:
            raise SimError("no free spot for the robot in this world; use another seed")
        if rng.random() < 0.7:
            yaw = _open_heading(world, start) + rng.normal(0, 0.3)
        else:
            yaw = rng.uniform(-math.pi, math.pi)
        self.pose = np.array([start[0], start[1], math.remainder(yaw, 2 * math.pi)])
        self.odom = self.pose.copy()
        self.vw = np.zeros(2)  # forward speed (m/s), turn rate (rad/s)
        self.direction = np.array([math.cos(yaw), math.sin(yaw)])
        self.route: list[np.ndarray] = []
        self.cruise = self.pause = self.pause_turn = 0.0
        self.check_pos = self.pose[:2].copy()
        self.check_timer = 0.0
        # Odometry errors come from their own generator, so the true motion is the same with
        # or without drift.
        self.odom_rng = np.random.default_rng(int(rng.integers(2**62)))
        drift = config.odom_drift
        self.scale = 1 + self.odom_rng.normal(0, drift, 2) if drift > 0 else np.ones(2)
        if config.moving:
            self._new_goal()

    def _new_goal(self) -> None:
        for _ in range(5):
            goal = self.world.sample_free(self.rng, clearance=0.6)
            route = None if goal is None else self.world.route(self.pose[:2], goal)
            if route:
                self.route = route
                self.cruise = self.rng.uniform(*self.cfg.cruise)
                return
        self.route = []
        self._pause()

    def _pause(self) -> None:
        self.pause = self.rng.uniform(*self.cfg.pause_time)
        self.pause_turn = (
            self.rng.choice([-1, 1]) * self.rng.uniform(0.3, 1.0) * (self.rng.random() < 0.4)
        )

    def _command(self, dt: float, people: np.ndarray) -> tuple[float, float]:
        cfg = self.cfg
        if self.pause > 0:
            self.pause -= dt
            if self.pause <= 0:
                self._new_goal()
            return 0.0, self.pause_turn * cfg.max_turn_rate
        xy, yaw = self.pose[:2], self.pose[2]
        while len(self.route) > 1 and math.dist(self.route[0], xy) < 0.5:
            self.route.pop(0)
        if not self.route or (len(self.route) == 1 and math.dist(self.route[0], xy) < 0.4):
            if self.rng.random() < cfg.pause_prob:
                self._pause()
            else:
                self._new_goal()
            return 0.0, 0.0
        self.check_timer += dt
        if self.check_timer > 4.0:
            if math.dist(xy, self.check_pos) < 0.3:
                self._new_goal()
            self.check_pos, self.check_timer = xy.copy(), 0.0
        to_wp = self.route[0] - xy
        direction = to_wp / max(math.hypot(*to_wp), 1e-6)
        # Keep clear of walls and furniture (gently: the speed limit below does the rest).
        field = self.world.field
        d, away_x, away_y = field.at(xy[0], xy[1])
        if d < 0.8:
            direction = direction + 0.4 * math.exp((0.4 - d) / 0.2) * np.array([away_x, away_y])
        heading = np.array([math.cos(yaw), math.sin(yaw)])
        slow = 1.0
        if len(people):
            rel = people - xy
            dist = np.hypot(rel[:, 0], rel[:, 1])
            along = rel @ heading
            across = np.abs(rel @ np.array([-heading[1], heading[0]]))
            in_path = (along > 0) & (across < 0.5) & (dist < 1.2)
            if in_path.any():
                slow = _clamp((float(dist[in_path].min()) - 0.45) / 0.6, 0.0, 1.0)
            close = dist < 1.2
            if close.any():
                push = -rel[close] / np.maximum(dist[close], 1e-6)[:, None]
                weight = 0.5 * np.exp((0.7 - dist[close]) / 0.3)
                direction = direction + (weight[:, None] * push).sum(0)
        # Low-pass the steering direction: a driver does not twitch at every push.
        self.direction = 0.75 * self.direction + 0.25 * direction
        err = math.remainder(math.atan2(self.direction[1], self.direction[0]) - yaw, 2 * math.pi)
        w = _clamp(1.5 * err, -cfg.max_turn_rate, cfg.max_turn_rate)
        # Slow down where the way ahead is narrow, so the bumper rarely has to act.
        ahead = field.at(xy[0] + 0.5 * heading[0], xy[1] + 0.5 * heading[1])[0]
        room = _clamp(0.2 + 3.0 * (ahead - cfg.radius), 0.0, 1.0)
        v = self.cruise * max(0.0, math.cos(err)) ** 2 * slow * max(room, 0.15)
        if len(self.route) == 1:
            v = min(v, 0.3 + math.hypot(*to_wp))  # ease into the goal
        return min(v, cfg.max_speed), w

    def step(self, dt: float, people: np.ndarray) -> None:
        """Advance by ``dt`` seconds; ``people`` are the ``(M, 2)`` positions of people nearby."""
        if not self.cfg.moving:
            return
        cfg = self.cfg
        new = drive(self.world, self.pose, self.vw, self._command(dt, people), cfg, dt)
        if cfg.odom_drift > 0:
            inc = relative(self.pose, new)
            dist = math.hypot(inc[0], inc[1])
            spread = np.array([dist, 0.2 * dist, abs(inc[2]) + 0.2 * dist])
            noise = self.odom_rng.normal(0, cfg.odom_drift, 3) * spread
            # one scale error for the distance driven, one for the turn
            self.odom = compose(self.odom, inc * self.scale[[0, 0, 1]] + noise)
        else:
            self.odom = new.copy()
        self.pose = new
