"""What a tracker hands the engine to carry: the objects it follows in one frame,
frozen, moved ``k`` frames on by their velocity and the sensor's guessed motion
(:meth:`lidarflow.tracking.Tracker.movers`, laid over a model's decided map by
:class:`lidarflow.predict.engine.Engine` where its policy says ``movers``)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lidarflow.geometry import rigid_moved

__all__ = ["Movers", "composed_motion"]


def composed_motion(motion: np.ndarray, steps: int) -> np.ndarray:
    """The pose after ``steps`` repeats of ``motion`` ``(dx, dy, dyaw)`` (each in the frame the
    last one reached), in the first frame: ``(3,)`` float64.

    >>> composed_motion(np.array([1.0, 0.0, np.pi / 2]), 2).round(6).tolist()
    [1.0, 1.0, 3.141593]
    """
    dx, dy, yaw = (float(v) for v in np.asarray(motion, np.float64).reshape(3))
    x = y = heading = 0.0
    for _ in range(steps):
        c, s = np.cos(heading), np.sin(heading)
        x, y, heading = x + c * dx - s * dy, y + s * dx + c * dy, heading + yaw
    return np.array([x, y, heading])


@dataclass(frozen=True)
class Movers:
    """The tracked objects of one frame, frozen (:meth:`Tracker.movers`): ``shape`` ``(H, W)``
    of the grid, per object its velocity ``(vx, vy)`` (cells per frame, sensor frame) and its
    cells ``(N, 2)`` ``(row, col)``; ``motion`` the ego motion guessed per frame (``None``: the
    sensor stands still); ``held`` ``(H, W)`` bool, the transient cells no track took (rarely
    occupied before, but beside a wall or still), kept where they are for ``hold`` frames."""

    shape: tuple[int, int]
    tracks: list[tuple[np.ndarray, np.ndarray]]
    motion: np.ndarray | None
    held: np.ndarray | None = None
    hold: int = 0

    def cells_at(self, k: int) -> np.ndarray:
        """``(H, W)`` bool: every object's cells shifted by ``k`` times its velocity (rounded
        to whole cells), in the sensor frame of the last frame."""
        h, w = self.shape
        out = np.zeros(self.shape, bool)
        for velocity, cells in self.tracks:
            d_row = int(np.rint(-k * velocity[0]))
            d_col = int(np.rint(-k * velocity[1]))
            r, c = cells[:, 0] + d_row, cells[:, 1] + d_col
            inside = (r >= 0) & (r < h) & (c >= 0) & (c < w)
            out[r[inside], c[inside]] = True
        return out

    def moved_to_sensor(self, image: np.ndarray, k: int) -> np.ndarray:
        """``image`` ``(H, W)`` of the last frame moved into the sensor frame ``k`` guessed
        steps on (unchanged on a still sensor): float32 in [0, 1]."""
        image = np.asarray(image, np.float32)
        if self.motion is not None:
            image = np.clip(rigid_moved(image, composed_motion(self.motion, k)), 0.0, 1.0)
        return image.astype(np.float32)

    def at(self, k: int) -> np.ndarray:
        """``(H, W)`` float32: the objects ``k`` frames on (and the held cells up to ``hold``),
        in the sensor frame then."""
        cells = self.cells_at(k)
        if self.held is not None and k <= self.hold:
            cells |= self.held
        return self.moved_to_sensor(cells, k)
