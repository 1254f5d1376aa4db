"""Walking people, seen by the LiDAR as two legs.

Each person is a point body steered by a social-force model (Helbing & Molnár 1995): a drive
towards the next waypoint of a route through the doors, exponential repulsion from other people
(mostly those in front), walls, furniture and the robot. People stop and turn on the spot, pick
new goals (often near the sensor), and leave: they vanish where the sensor cannot see and later
reappear elsewhere unseen.

Legs: two circles beside the body's centre line that swing along the walking direction with the
gait phase; with the swing amplitude ``A = L / (2 pi)`` for a gait cycle of length ``L``, each
leg's speed is ``v (1 +/- cos(phase))``: one leg rests while the other swings at twice the body
speed. Standing people have both legs side by side.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lidarflow.errors import SimError
from lidarflow.sim.world import World

__all__ = ["Crowd", "PeopleConfig", "legs_from"]

WALK, STOP, OFF = 0, 1, 2


#: The most people in the building at once: a crowd fills the offices long before this, and
#: the pairwise forces between them take memory as the square of the count.
MAX_PEOPLE = 500


@dataclass(frozen=True)
class PeopleConfig:
    """People's numbers, sizes and behaviour (SI units)."""

    count: int = 8
    speed_range: tuple[float, float] = (0.3, 1.8)
    speed_mean: float = 1.2
    speed_std: float = 0.35
    leg_radius: tuple[float, float] = (0.06, 0.08)
    hip_half_width: tuple[float, float] = (0.08, 0.12)
    body_radius: float = 0.25
    near_goal_prob: float = 0.55
    near_range: tuple[float, float] = (1.0, 5.0)
    stop_prob: float = 0.3
    stop_time: tuple[float, float] = (1.0, 6.0)
    leave_prob: float = 0.25
    respawn_delay: tuple[float, float] = (0.5, 6.0)
    relax_time: float = 0.5
    people_strength: float = 2.1
    people_range: float = 0.3
    wall_strength: float = 6.0
    wall_range: float = 0.15

    def __post_init__(self) -> None:
        lo, hi = self.speed_range
        if self.count < 0 or not 0 < lo <= hi:
            raise SimError(f"people: count must be >= 0 and 0 < speed_min <= speed_max: {self}")
        if self.count > MAX_PEOPLE:
            raise SimError(
                f"people (--people): at most {MAX_PEOPLE} at once (their pairwise forces take "
                f"memory as the count squared), got {self.count}"
            )


def legs_from(snapshots: np.ndarray, hip: np.ndarray, leg_r: np.ndarray) -> np.ndarray:
    """Leg circles ``(T, 2P, 3)`` as ``(x, y, r)`` from ``(T, P, 5)`` snapshots
    (:meth:`Crowd.snapshot`); person ``i`` owns rows ``2i`` (left) and ``2i + 1`` (right); people
    who are not there have NaN rows."""
    x, y, heading, phase, speed = np.moveaxis(snapshots, -1, 0)
    cycle = 0.8 + 0.45 * speed
    swing = cycle / (2 * math.pi) * np.minimum(1.0, speed / 0.3) * np.sin(phase)
    hx, hy = np.cos(heading), np.sin(heading)
    out = np.empty((*x.shape, 2, 3))
    out[..., 0, 0] = x - hip * hy + swing * hx
    out[..., 0, 1] = y + hip * hx + swing * hy
    out[..., 1, 0] = x + hip * hy - swing * hx
    out[..., 1, 1] = y - hip * hx - swing * hy
    out[..., 2] = np.where(np.isnan(x), np.nan, leg_r)[..., None]
    return out.reshape(*x.shape[:-1], -1, 3)


def _wrap(a: np.ndarray | float) -> np.ndarray | float:
    return np.mod(np.asarray(a) + math.pi, 2 * math.pi) - math.pi


class Crowd:
    """``config.count`` person slots in ``world``; ``sensor`` is ``(x, y, yaw)`` of the LiDAR,
    ``fov`` (rad) and ``reach`` (m) what it sees, used to choose goals near it and to hide
    appearing and vanishing people from it."""

    #: The longest integration step (s) of the forces.
    substep = 0.07

    def __init__(
        self,
        world: World,
        config: PeopleConfig,
        rng: np.random.Generator,
        sensor: np.ndarray,
        fov: float,
        reach: float,
    ) -> None:
        self.world, self.cfg, self.rng = world, config, rng
        self.fov, self.reach = fov, reach
        n = config.count
        lo, hi = config.speed_range
        self.speed0 = np.clip(rng.normal(config.speed_mean, config.speed_std, n), lo, hi)
        self.leg_r = rng.uniform(*config.leg_radius, n)
        self.hip = rng.uniform(*config.hip_half_width, n)
        self.heading = rng.uniform(-math.pi, math.pi, n)
        self.phase = rng.uniform(0, 2 * math.pi, n)
        self.state = np.full(n, OFF)
        self.routes: list[list[np.ndarray]] = [[] for _ in range(n)]
        # per person: positions and velocities (m, m/s), then times (s), speeds, turn rates
        self.pos, self.vel, self.target, self.check_pos = (np.zeros((n, 2)) for _ in range(4))
        self.timer, self.check_timer, self._speed, self.turn = (np.zeros(n) for _ in range(4))
        self.leaving, self.final = np.zeros(n, dtype=bool), np.zeros(n, dtype=bool)
        for i in range(n):
            if rng.random() < 0.75:
                p = world.sample_free(rng)
                if p is not None:
                    self._activate(i, p, sensor)
                    continue
            self.timer[i] = rng.uniform(0, config.respawn_delay[1])

    # ------------------------------------------------------------- behaviour
    def _hidden(self, sensor: np.ndarray, xy: np.ndarray) -> np.ndarray:
        xy = np.atleast_2d(xy)
        d = xy - sensor[:2]
        far = np.hypot(d[:, 0], d[:, 1]) > self.reach + 0.5
        behind = np.abs(_wrap(np.arctan2(d[:, 1], d[:, 0]) - sensor[2])) > self.fov / 2 + 0.1
        return far | behind | self.world.occluded(sensor[:2], xy)

    def _spawn_point(self, sensor: np.ndarray) -> np.ndarray | None:
        """A free place the sensor cannot see, preferably close to it (behind it, or behind a
        wall or a door), so that people walk into view from where real people would."""
        rng, k = self.rng, 12
        dist = rng.uniform(1.5, 7.0, k)
        pts, ok = self._open_around(sensor, dist, rng.uniform(-math.pi, math.pi, k))
        ok[ok] = self._hidden(sensor, pts[ok])
        if ok.any():
            return pts[np.argmax(ok)]
        p = self.world.sample_free(rng, tries=8)
        if p is not None and math.dist(p, sensor[:2]) > 1.5 and self._hidden(sensor, p)[0]:
            return p
        return None

    def _open_around(
        self, sensor: np.ndarray, dist: np.ndarray, bearing: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """The points at ``dist`` and world ``bearing`` from the sensor, and which of them lie in
        a reachable room, clear of obstacles."""
        pts = sensor[:2] + np.column_stack([dist * np.cos(bearing), dist * np.sin(bearing)])
        rooms = self.world.room_of(pts)
        ok = (rooms >= 0) & self.world.reachable[np.maximum(rooms, 0)]
        return pts, ok & (self.world.clearance(pts) >= 0.45)

    def _activate(self, i: int, p: np.ndarray, sensor: np.ndarray) -> None:
        self.pos[i] = p
        self.vel[i] = 0.0
        self.state[i] = WALK
        self.leaving[i] = False
        self.check_pos[i] = p
        self.check_timer[i] = 0.0
        self._new_goal(i, sensor)

    def _goal_point(self, i: int, sensor: np.ndarray) -> np.ndarray | None:
        rng, cfg, world = self.rng, self.cfg, self.world
        if self.leaving[i]:
            for _ in range(4):
                p = world.sample_free(rng)
                if p is not None and self._hidden(sensor, p)[0]:
                    return p
            return None
        if rng.random() < cfg.near_goal_prob:
            k = 16
            dist = rng.uniform(*cfg.near_range, k)
            bearing = sensor[2] + rng.uniform(-0.45, 0.45, k) * min(self.fov, math.pi)
            pts, ok = self._open_around(sensor, dist, bearing)
            if ok.any():
                return pts[np.argmax(ok)]
        return world.sample_free(rng)

    def _new_goal(self, i: int, sensor: np.ndarray) -> None:
        self.leaving[i] = self.rng.random() < self.cfg.leave_prob
        for _ in range(3):
            goal = self._goal_point(i, sensor)
            route = None if goal is None else self.world.route(self.pos[i], goal)
            if route:
                self.routes[i] = route
                self.state[i] = WALK
                return
        self.routes[i] = []
        self._stop(i)

    def _stop(self, i: int) -> None:
        self.state[i] = STOP
        self.timer[i] = self.rng.uniform(*self.cfg.stop_time)
        self.turn[i] = self.rng.uniform(-1.2, 1.2) if self.rng.random() < 0.5 else 0.0

    def _deciders(self) -> range | np.ndarray:
        """The people who choose their own goals, stops and exits (here everyone)."""
        return range(len(self.pos))

    def _update_states(self, dt: float, sensor: np.ndarray) -> None:
        rng, cfg = self.rng, self.cfg
        self.timer[self.state != WALK] -= dt
        for i in self._deciders():
            state = self.state[i]
            if state == OFF:
                if self.timer[i] <= 0:
                    p = self._spawn_point(sensor)
                    if p is not None:
                        self._activate(i, p, sensor)
                    else:
                        self.timer[i] = 0.5
                continue
            if state == STOP:
                if self.timer[i] <= 0:
                    self._new_goal(i, sensor)
                continue
            route = self.routes[i]
            here = (float(self.pos[i, 0]), float(self.pos[i, 1]))
            while len(route) > 1 and math.dist(route[0], here) < 0.5:
                route.pop(0)
            self.check_timer[i] += dt
            if self.check_timer[i] > 2.5:  # no progress: give up this goal
                stuck = math.dist(here, self.check_pos[i]) < 0.3
                self.check_pos[i] = here
                self.check_timer[i] = 0.0
                if stuck:
                    self._new_goal(i, sensor)
                    continue
            if len(route) == 1 and math.dist(route[0], here) < 0.4:
                if self.leaving[i]:
                    if self._hidden(sensor, self.pos[i])[0]:
                        self.state[i] = OFF
                        self.timer[i] = rng.uniform(*cfg.respawn_delay)
                    else:
                        self._new_goal(i, sensor)
                elif rng.random() < cfg.stop_prob:
                    self._stop(i)
                else:
                    self._new_goal(i, sensor)
        # Where each walker heads now, for the vectorised forces.
        for i in np.flatnonzero(self.state == WALK):
            route = self.routes[i]
            self.target[i] = route[0]
            self.final[i] = len(route) == 1

    # ------------------------------------------------------------- dynamics
    def _drive(self, idx: np.ndarray, relax_time: float) -> tuple[np.ndarray, np.ndarray]:
        """The drive of people ``idx`` towards their targets at their preferred speeds (slowing
        on the last metre before a goal) and their unit walking directions (the heading when
        nearly still), each ``(len(idx), 2)``."""
        pos, vel = self.pos[idx], self.vel[idx]
        d = self.target[idx] - pos
        n = np.hypot(d[:, 0], d[:, 1])
        v0 = self.speed0[idx] * np.where(self.final[idx], np.minimum(1.0, n), 1.0)
        v0 *= self.state[idx] == WALK
        force = (d * (v0 / np.maximum(n, 1e-6))[:, None] - vel) / relax_time
        speed = np.hypot(vel[:, 0], vel[:, 1])
        facing = np.where(
            speed[:, None] > 0.1,
            vel / np.maximum(speed, 1e-9)[:, None],
            np.column_stack([np.cos(self.heading[idx]), np.sin(self.heading[idx])]),
        )
        return force, facing

    def _forces(self, idx: np.ndarray, robot: np.ndarray, robot_radius: float) -> np.ndarray:
        cfg = self.cfg
        pos = self.pos[idx]
        force, facing = self._drive(idx, cfg.relax_time)
        others = np.concatenate([pos, robot[None, :2]])
        radii = np.concatenate([np.full(len(pos), cfg.body_radius), [robot_radius]])
        diff = pos[:, None, :] - others[None, :, :]
        dist = np.maximum(np.hypot(diff[..., 0], diff[..., 1]), 1e-6)
        dist[np.arange(len(pos)), np.arange(len(pos))] = np.inf
        n_ij = diff / dist[..., None]
        # Anisotropy: people react mostly to what is in front of them.
        cos_phi = -(n_ij * facing[:, None, :]).sum(-1)
        weight = 0.35 + 0.65 * (1 + cos_phi) / 2
        overlap = (cfg.body_radius + radii[None, :] - dist) / cfg.people_range
        mag = cfg.people_strength * np.exp(overlap) * weight
        force += (mag[..., None] * n_ij).sum(1)

        # Walls and furniture: the nearest one, from the world's distance table.
        dist_w, away = self.world.field.lookup(pos)
        mag = cfg.wall_strength * np.exp((cfg.body_radius - dist_w) / cfg.wall_range)
        force += (mag * (dist_w < self.world.field.cap))[:, None] * away
        return force

    def step(self, dt: float, sensor: np.ndarray, robot_radius: float = 0.35) -> None:
        """Advance by ``dt`` seconds. ``sensor`` is the LiDAR's (= robot's) pose."""
        self._update_states(dt, sensor)
        idx = np.flatnonzero(self.state != OFF)
        if idx.size == 0:
            return
        substeps = max(1, math.ceil(dt / self.substep))
        h = dt / substeps
        for _ in range(substeps):
            force = self._forces(idx, sensor, robot_radius)
            vel = self.vel[idx] + h * force
            speed = np.hypot(vel[:, 0], vel[:, 1])
            cap = np.where(
                self.state[idx] == WALK,
                np.minimum(1.3 * self.speed0[idx], self.cfg.speed_range[1]),
                0.6,
            )
            vel *= np.minimum(1.0, cap / np.maximum(speed, 1e-9))[:, None]
            self.vel[idx] = vel
            self.pos[idx] += h * vel
        # Keep bodies out of walls whatever the forces did.
        clear = self.world.clearance(self.pos[idx])
        bad = clear < 0.2
        if bad.any():
            self.pos[idx[bad]] -= h * self.vel[idx[bad]] * substeps
            self.vel[idx[bad]] *= 0.0
        speed = np.hypot(self.vel[idx, 0], self.vel[idx, 1])
        moving = speed > 0.12
        target = np.arctan2(self.vel[idx, 1], self.vel[idx, 0])
        turn = np.where(
            moving,
            np.clip(_wrap(target - self.heading[idx]), -4 * dt, 4 * dt),
            np.where(self.state[idx] == STOP, self.turn[idx] * dt, 0.0),
        )
        self.heading[idx] = _wrap(self.heading[idx] + turn)
        cycle = 0.8 + 0.45 * speed
        self.phase[idx] = np.mod(self.phase[idx] + 2 * math.pi * speed * dt / cycle, 2 * math.pi)
        self._speed[:] = 0.0
        self._speed[idx] = speed

    def snapshot(self) -> np.ndarray:
        """The state the legs are drawn from, ``(count, 5)``: x, y, heading, gait phase, speed
        (NaN rows for people who are not there); see :func:`legs_from`."""
        snap = np.column_stack([self.pos, self.heading, self.phase, self._speed])
        snap[self.state == OFF] = np.nan
        return snap

    def legs(self) -> np.ndarray:
        """Leg circles ``(2 * count, 3)`` now; see :func:`legs_from`."""
        return legs_from(self.snapshot()[None], self.hip, self.leg_r)[0]

    def walking(self) -> np.ndarray:
        """Which people are present, ``(count,)`` bool."""
        return self.state != OFF
