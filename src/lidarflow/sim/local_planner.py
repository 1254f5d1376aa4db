"""A sampling local planner for a differential-drive robot over obstacle maps that change in time.

Every control step it tries ``speeds x turns`` target commands ``(v, w)`` (``v`` from 0 to the
top speed, ``w`` across the turn-rate range), rolls each out for ``K`` steps of ``dt`` from the
robot's current ``(v, w)`` under its acceleration limits (the unicycle the robot is), and keeps
the cheapest. Everything is in the robot's frame at planning time (the scan's: x forward,
y left, :mod:`lidarflow.scan`'s grid), so rollout step ``k`` (``1..K``) is checked against the
obstacle map ``k`` frames ahead: a map that moves with time (a prediction) and a map that does
not (the last scan, given once) are scored by the same rule.

Cost of a rollout, smallest wins:

* **collision**: where its disc, grown by ``margin``, reaches an occupied cell (value >= 0.5)
  at some step, ``1000 * (K + 1 - first such step)``: a robot with no way out takes the one
  that hits latest (usually stopping);
* **proximity**: ``obstacle_weight * exp(-(min_k clearance_k - radius - margin) / reach)``;
* **goal**: ``goal_weight`` times the distance from the rollout's end to the goal (no heading
  term: one keeps the robot facing a wall between it and the goal);
* **speed**: ``speed_weight * (max_speed - v)``, so that it does not dawdle.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lidarflow.errors import SimError
from lidarflow.scan import GridSpec, cell_centres

__all__ = ["LocalPlanner", "PlannerConfig", "RobotConfig", "rollouts"]


@dataclass(frozen=True)
class RobotConfig:
    """The differential-drive robot (SI units): a disc of ``radius`` with unicycle limits."""

    radius: float = 0.3
    max_speed: float = 1.0
    max_turn_rate: float = 1.5
    accel: float = 1.0
    turn_accel: float = 3.0

    def __post_init__(self) -> None:
        if min(self.radius, self.max_speed, self.max_turn_rate, self.accel, self.turn_accel) <= 0:
            raise SimError(f"the robot's size and limits must be > 0: {self}")


@dataclass(frozen=True)
class PlannerConfig:
    """The planner's samples and weights (see the module docstring; lengths in metres)."""

    speeds: int = 5
    turns: int = 11
    margin: float = 0.2
    reach: float = 0.3
    obstacle_weight: float = 1.0
    goal_weight: float = 1.0
    speed_weight: float = 0.5


def rollouts(
    v: float, w: float, targets: np.ndarray, robot: RobotConfig, dt: float, steps: int
) -> np.ndarray:
    """``(S, steps, 3)`` poses ``(x, y, yaw)`` after each of ``steps`` steps of ``dt`` s, from
    the origin moving at ``(v, w)``, towards each target command of ``targets (S, 2)`` under
    ``robot``'s acceleration limits (midpoint integration, as the simulator drives it)."""
    s = len(targets)
    vel, turn = np.full(s, float(v)), np.full(s, float(w))
    pose = np.zeros((s, 3))
    out = np.empty((s, steps, 3))
    for k in range(steps):
        vel += np.clip(targets[:, 0] - vel, -robot.accel * dt, robot.accel * dt)
        turn += np.clip(targets[:, 1] - turn, -robot.turn_accel * dt, robot.turn_accel * dt)
        mid = pose[:, 2] + turn * dt / 2
        pose = pose + np.column_stack([vel * dt * np.cos(mid), vel * dt * np.sin(mid), turn * dt])
        out[:, k] = pose
    return out


class LocalPlanner:
    """Chooses the next command from obstacle maps ``(K, H, W)`` on ``grid`` (module doc)."""

    def __init__(
        self,
        grid: GridSpec,
        dt: float,
        robot: RobotConfig | None = None,
        config: PlannerConfig | None = None,
    ) -> None:
        self.grid, self.dt = grid, dt
        self.robot = robot or RobotConfig()
        self.config = config or PlannerConfig()
        r, c = self.robot, self.config
        v = np.linspace(0.0, r.max_speed, c.speeds)
        w = np.linspace(-r.max_turn_rate, r.max_turn_rate, c.turns)
        self.targets = np.stack(np.meshgrid(v, w, indexing="ij"), -1).reshape(-1, 2)
        x, y = cell_centres(grid)
        self._xy = np.stack([x, y], -1)

    def _clearance(self, paths: np.ndarray, maps: np.ndarray) -> np.ndarray:
        """``(S, K)`` distance from each rollout pose to the nearest occupied cell of its map."""
        steps = paths.shape[1]
        reach = self.robot.max_speed * steps * self.dt + self.robot.radius + 1.0
        out = np.full(paths.shape[:2], np.inf)
        for k in range(steps):
            occupied = maps[min(k, len(maps) - 1)] >= 0.5
            pts = self._xy[occupied]
            pts = pts[np.hypot(pts[:, 0], pts[:, 1]) < reach]
            if len(pts):
                d = paths[:, k, None, :2] - pts[None]
                out[:, k] = np.sqrt((d**2).sum(-1)).min(1)
        return out

    def command(
        self, maps: np.ndarray, goal: np.ndarray, v: float, w: float
    ) -> tuple[float, float]:
        """The target ``(v, w)`` for the next control step: ``maps`` ``(K, H, W)`` (or one
        ``(H, W)`` map for all steps) occupied where >= 0.5, ``goal`` ``(2,)`` in metres in the
        robot's frame, ``(v, w)`` what the robot does now."""
        maps = np.asarray(maps)
        if maps.ndim == 2:
            maps = maps[None]
        if maps.shape[-2:] != self.grid.shape:
            raise SimError(f"obstacle maps must be {self.grid.shape}, got {maps.shape[-2:]}")
        r, c = self.robot, self.config
        steps = max(len(maps), 1)
        paths = rollouts(v, w, self.targets, r, self.dt, steps)
        free = self._clearance(paths, maps) - r.radius - c.margin
        hit = free < 0
        first = np.where(hit.any(1), hit.argmax(1), steps)
        cost = 1000.0 * (steps - first)
        cost += c.obstacle_weight * np.exp(-np.maximum(free.min(1), 0) / c.reach)
        end = paths[:, -1]
        to_goal = goal[None] - end[:, :2]
        cost += c.goal_weight * np.hypot(to_goal[:, 0], to_goal[:, 1])
        cost += c.speed_weight * (r.max_speed - self.targets[:, 0])
        best = int(np.argmin(cost))
        return float(self.targets[best, 0]), float(self.targets[best, 1])
