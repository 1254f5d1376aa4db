"""A lookup table of the distance to the nearest obstacle, and the direction away from it."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

__all__ = ["DistanceField"]


class DistanceField:
    """Distance (m, capped at ``cap``) from every point of a fine grid to the nearest segment or
    circle, and the unit vector pointing away from it: a table lookup replaces testing every wall
    at every simulation step. Built segment by segment over each one's neighbourhood only."""

    def __init__(
        self,
        segments: np.ndarray,
        circles: np.ndarray,
        bounds: tuple[float, float, float, float],
        res: float = 0.05,
        cap: float = 1.5,
    ) -> None:
        self.res, self.cap = res, cap
        self.origin = np.array([bounds[0] - cap, bounds[1] - cap])
        nx = math.ceil((bounds[2] - bounds[0] + 2 * cap) / res)
        ny = math.ceil((bounds[3] - bounds[1] + 2 * cap) / res)
        self.dist = np.full((ny, nx), cap)
        self.away = np.zeros((ny, nx, 2))
        self._last = np.array([nx - 1, ny - 1])
        self._ox, self._oy = float(self.origin[0]), float(self.origin[1])
        self._nx, self._ny = nx - 1, ny - 1
        for x0, y0, x1, y1 in segments:
            box = (min(x0, x1), min(y0, y1), max(x0, x1), max(y0, y1))
            self._stamp(box, _to_segment, (x0, y0, x1, y1))
        for cx, cy, r in circles:
            self._stamp((cx - r, cy - r, cx + r, cy + r), _to_circle, (cx, cy, r))

    def _stamp(self, box: tuple[float, ...], nearest: Callable, shape: tuple[float, ...]) -> None:
        """Keep ``nearest(px, py, *shape)`` where it is nearer, over ``box`` grown by ``cap``."""
        x0, y0, x1, y1 = box
        res, cap = self.res, self.cap
        i0 = max(int((x0 - cap - self.origin[0]) / res), 0)
        i1 = min(int((x1 + cap - self.origin[0]) / res) + 1, self.dist.shape[1])
        j0 = max(int((y0 - cap - self.origin[1]) / res), 0)
        j1 = min(int((y1 + cap - self.origin[1]) / res) + 1, self.dist.shape[0])
        px = self.origin[0] + (np.arange(i0, i1) + 0.5) * res
        py = self.origin[1] + (np.arange(j0, j1) + 0.5) * res
        px, py = np.meshgrid(px, py)
        d, ax, ay = nearest(px, py, *shape)
        view = self.dist[j0:j1, i0:i1]
        better = d < view
        view[better] = d[better]
        self.away[j0:j1, i0:i1, 0][better] = ax[better]
        self.away[j0:j1, i0:i1, 1][better] = ay[better]

    def at(self, x: float, y: float) -> tuple[float, float, float]:
        """``(distance, away_x, away_y)`` at one point: the scalar :meth:`lookup`, without
        array overhead (the robot asks several times per step)."""
        i = min(max(int((x - self._ox) / self.res), 0), self._nx)
        j = min(max(int((y - self._oy) / self.res), 0), self._ny)
        return self.dist.item(j, i), self.away.item(j, i, 0), self.away.item(j, i, 1)

    def lookup(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(distance (N,), away (N, 2))`` at points ``(N, 2)`` (nearest grid point)."""
        xy = np.atleast_2d(xy)
        ij = ((xy - self.origin) / self.res).astype(np.int64)
        np.minimum(np.maximum(ij, 0, out=ij), self._last, out=ij)
        return self.dist[ij[:, 1], ij[:, 0]], self.away[ij[:, 1], ij[:, 0]]


def _to_segment(
    px: np.ndarray, py: np.ndarray, x0: float, y0: float, x1: float, y1: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    ex, ey = x1 - x0, y1 - y0
    u = np.clip(((px - x0) * ex + (py - y0) * ey) / max(ex * ex + ey * ey, 1e-12), 0.0, 1.0)
    dx, dy = px - x0 - u * ex, py - y0 - u * ey
    d = np.maximum(np.hypot(dx, dy), 1e-9)
    return d, dx / d, dy / d


def _to_circle(
    px: np.ndarray, py: np.ndarray, cx: float, cy: float, r: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    dx, dy = px - cx, py - cy
    n = np.maximum(np.hypot(dx, dy), 1e-9)
    return np.maximum(n - r, 1e-9), dx / n, dy / n
