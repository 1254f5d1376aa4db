"""Where a navigating robot's planner takes its obstacles from: four sources of ``(K, H, W)`` maps.

Each source is given what the robot senses at frame ``t`` (a :class:`Sensed`) and returns the
obstacle maps ``1..K`` frames ahead, float32 in [0, 1] (occupied where >= 0.5), in the sensor
frame at ``t``:

* ``last_scan``: the occupancy of the scan at ``t``, the same for every ``k``;
* ``lidarflow``: a :class:`~lidarflow.predict.Predictor`'s decided maps (the caller makes it:
  ``sim`` does not import ``predict``), moved back into the frame at ``t`` (cells not covered
  are free);
* ``tracker``: :class:`lidarflow.tracking.Tracker`'s maps, given the true motion, moved back;
* ``true_future``: the ceiling: the scan's cells on walls and furniture, and the people's legs
  ``k`` frames on (:attr:`Sensed.future_legs`), occluded or not.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from lidarflow.errors import SimError
from lidarflow.geometry import metric_to_cell
from lidarflow.motion.odometry import metres_to_cells, relative_motions
from lidarflow.outputs.planner import steps_in_scan_frame
from lidarflow.scan import GridSpec, Scan
from lidarflow.tracking import Tracker

__all__ = ["SOURCES", "ObstacleSource", "Sensed", "make_source"]

SOURCES = ("last_scan", "lidarflow", "tracker", "true_future")


@dataclass(frozen=True)
class Sensed:
    """What the robot senses at one frame. ``pose``: the true sensor pose ``(x, y, yaw)`` in the
    world (the robot's odometry, driftless); ``occupancy``, ``visibility``: the scan's maps;
    ``static``: its occupied cells hit on walls and furniture; ``future_legs``: ``(K, L, 3)``
    the people's leg circles ``(x, y, r)`` in the world ``1..K`` frames on (NaN rows for
    people not there), only for sources that ask (``wants_future``)."""

    scan: Scan
    pose: np.ndarray
    occupancy: np.ndarray
    visibility: np.ndarray
    static: np.ndarray
    future_legs: np.ndarray | None = None


class ObstacleSource(Protocol):
    """Obstacle maps for the planner, one call per frame, in order (module docstring)."""

    name: str
    horizon: int
    wants_future: bool

    def maps(self, sensed: Sensed) -> np.ndarray: ...


class _LastScan:
    name, wants_future = "last_scan", False

    def __init__(self, grid: GridSpec, horizon: int) -> None:
        self.horizon = horizon

    def maps(self, sensed: Sensed) -> np.ndarray:
        occupied = np.asarray(sensed.occupancy, np.float32)
        return np.broadcast_to(occupied, (self.horizon, *occupied.shape))


def _in_scan_frame(horizon: np.ndarray, motion: np.ndarray | None) -> np.ndarray:
    """Maps ``1..K`` ahead, each in the sensor frame ``k`` steps of ``motion`` on, moved back
    into the frame they were predicted from (decided where >= 0.5, not covered: free)."""
    _, occupied, covered = steps_in_scan_frame(horizon, horizon >= 0.5, motion)
    return (occupied & covered).astype(np.float32)


class _Lidarflow:
    name, wants_future = "lidarflow", False

    def __init__(self, grid: GridSpec, horizon: int, predictor: Any) -> None:
        self.horizon = horizon
        if predictor is None:
            raise SimError("the lidarflow source needs a Predictor (lidarflow.predict)")
        if predictor.horizon != horizon or predictor.grid != grid:
            raise SimError("the predictor's horizon and grid must be the source's")
        predictor.reset()
        self.predictor = predictor

    def maps(self, sensed: Sensed) -> np.ndarray:
        p = self.predictor.update(sensed.scan, pose=sensed.pose)
        decided = np.asarray(p.horizon_occupied, np.float32)
        return _in_scan_frame(decided, p.ahead_motion)


class _Tracker:
    name, wants_future = "tracker", False

    def __init__(self, grid: GridSpec, horizon: int) -> None:
        self.horizon, self.res = horizon, grid.res
        self.tracker = Tracker(res=grid.res)
        self.last_pose: np.ndarray | None = None

    def maps(self, sensed: Sensed) -> np.ndarray:
        motion = None
        if self.last_pose is not None:
            moved, _ = relative_motions(np.stack([self.last_pose, sensed.pose]))
            motion = metres_to_cells(moved[1], self.res)
        self.last_pose = np.asarray(sensed.pose, np.float64)
        self.tracker.observe(sensed.occupancy, sensed.visibility, motion)
        ahead = np.stack(self.tracker.ahead(self.horizon))
        return _in_scan_frame(ahead, motion)


class _TrueFuture:
    name, wants_future = "true_future", True

    def __init__(self, grid: GridSpec, horizon: int) -> None:
        self.horizon, self.grid = horizon, grid
        # the cells around a leg's that its disc may reach (legs are under 0.1 m across)
        reach = np.arange(-2, 3)
        self._near = np.stack(np.meshgrid(reach, reach, indexing="ij"), -1).reshape(-1, 2)

    def _discs(self, local: np.ndarray, radii: np.ndarray) -> np.ndarray:
        """``(H, W)`` the cells whose centre lies within a disc (radius plus half a cell) of
        the discs at ``local (N, 2)`` metres in the sensor frame."""
        g = self.grid
        h, w = g.shape
        centre = np.column_stack(metric_to_cell(local[:, 0], local[:, 1], h, w, g.res))
        cells = np.round(centre)[:, None, :].astype(np.int64) + self._near[None]
        gap = np.hypot(*(cells - centre[:, None, :]).transpose(2, 0, 1)) * g.res
        inside = (cells[..., 0] >= 0) & (cells[..., 0] < h) & (cells[..., 1] >= 0)
        inside &= (cells[..., 1] < w) & (gap <= radii[:, None] + g.res / 2)
        out = np.zeros(g.shape, np.float32)
        out[cells[inside][:, 0], cells[inside][:, 1]] = 1.0
        return out

    def maps(self, sensed: Sensed) -> np.ndarray:
        if sensed.future_legs is None:
            raise SimError("true_future needs the legs ahead (Sensed.future_legs)")
        out = np.repeat(np.asarray(sensed.static, np.float32)[None], self.horizon, 0)
        x0, y0, yaw = sensed.pose
        c, s = np.cos(yaw), np.sin(yaw)
        for k, legs in enumerate(sensed.future_legs[: self.horizon]):
            legs = legs[~np.isnan(legs[:, 0])]
            dx, dy = legs[:, 0] - x0, legs[:, 1] - y0
            local = np.column_stack([c * dx + s * dy, -s * dx + c * dy])
            out[k] = np.maximum(out[k], self._discs(local, legs[:, 2]))
        return out


def make_source(name: str, grid: GridSpec, horizon: int, predictor: Any = None) -> ObstacleSource:
    """The source ``name`` (one of :data:`SOURCES`) of maps ``1..horizon`` frames ahead on
    ``grid``; ``predictor``: a :class:`~lidarflow.predict.Predictor` of that horizon and grid
    for ``lidarflow`` (needed there; reset here, so one serves episode after episode)."""
    if horizon < 1:
        raise SimError(f"horizon must be >= 1 frame, got {horizon}")
    if name == "lidarflow":
        return _Lidarflow(grid, horizon, predictor)
    kinds = {"last_scan": _LastScan, "tracker": _Tracker, "true_future": _TrueFuture}
    if name not in kinds:
        raise SimError(f"obstacle source must be one of {SOURCES}, got {name!r}")
    return kinds[name](grid, horizon)
