"""What the tracker hands on each frame: the objects it follows, frozen (:class:`Tracks`, which
the engine lays over a model's decided map), and each as a :class:`Track` in metres and seconds
for the robot's own code (``Prediction.tracks``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from lidarflow.compiled import available, kernel, ready
from lidarflow.geometry import rigid_moved

__all__ = ["Track", "Tracks", "composed_motion"]


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
class Track:
    """One object the tracker follows, in the sensor frame of the scan just given (x forward,
    y left, metres; the sensor at the origin).

    Attributes:
        position: ``(2,)`` its centroid ``(x, y)``, metres.
        velocity: ``(2,)`` ``(vx, vy)`` in metres per second; ``None`` while the stream's step
            between scans is unknown (maps, or scans without stamps). Over the ground where the
            sensor's motion is known (the tracker takes it out), else relative to the sensor.
        frame_velocity: ``(2,)`` the same velocity in metres per frame (always known).
        cells: ``(N, 2)`` int, the ``(row, col)`` of its occupied cells in the grid.
    """

    position: np.ndarray
    velocity: np.ndarray | None
    frame_velocity: np.ndarray
    cells: np.ndarray


@dataclass(frozen=True)
class Tracks:
    """The objects tracked in one frame, frozen (:meth:`Tracker.tracks`): ``shape`` ``(H, W)``
    of the grid and ``res`` its cell size (metres); ``objects``, per object seen this frame its
    state ``(x, y, vx, vy)`` (cells and cells per frame, sensor frame, x forward, y left) and
    its cells ``(N, 2)`` ``(row, col)``; ``motion`` the ego motion guessed per frame (``None``:
    the sensor stands still). ``held`` ``(H, W)`` bool: the *held* cells, occupied cells that
    are not background yet no track took (mostly a person beside a wall, whose cells the wall's
    background hides from the foreground); they stay where they are for ``hold`` frames."""

    shape: tuple[int, int]
    objects: list[tuple[np.ndarray, np.ndarray]]
    motion: np.ndarray | None
    held: np.ndarray | None = None
    hold: int = 0
    res: float = 0.1
    # at(k) and cells_at(k) once per k: a roll-out, the tracking baseline's map and the online
    # combination's experts all ask for them
    _at: dict[int, np.ndarray] = field(default_factory=dict, init=False, repr=False, compare=False)
    _cells: dict[int, np.ndarray] = field(
        default_factory=dict, init=False, repr=False, compare=False
    )

    def metric(self, step_ns: int | None = None) -> tuple[Track, ...]:
        """Each object as a :class:`Track` (metres; metres per second given the stream's step
        ``step_ns``, nanoseconds)."""
        out = []
        for state, cells in self.objects:
            frame_velocity = np.asarray(state[2:4], np.float64) * self.res
            velocity = frame_velocity * (1e9 / step_ns) if step_ns else None
            position = np.asarray(state[:2], np.float64) * self.res
            out.append(Track(position, velocity, frame_velocity, cells.copy()))
        return tuple(out)

    def cells_at(self, k: int) -> np.ndarray:
        """``(H, W)`` bool, read-only: every object's cells shifted by ``k`` times its velocity
        (rounded to whole cells), in the sensor frame of the last frame."""
        if k not in self._cells:
            cells = self._shifted_cells(k)
            cells.setflags(write=False)
            self._cells[k] = cells
        return self._cells[k]

    def _shifted_cells(self, k: int) -> np.ndarray:
        # the tracker's int64 cells and float64 states only: NumPy does narrower types' sums
        # and products in their own width
        if not available() or not all(_wide(s, c) for s, c in self.objects):
            return self._cells_at_numpy(k)
        out = np.zeros(self.shape, bool)
        if self.objects:
            state, cells = self.objects[0]
            if not ready(_cells_at_loop, cells, float(state[2]), float(state[3]), int(k), out):
                return self._cells_at_numpy(k)
        for state, cells in self.objects:
            # one call an object: packing them all first costs more than the calls
            if not _cells_at_loop(cells, float(state[2]), float(state[3]), int(k), out):
                return self._cells_at_numpy(k)  # a shift out of all bounds: as the reference
        return out

    def _cells_at_numpy(self, k: int) -> np.ndarray:
        """:meth:`cells_at` in NumPy (the reference)."""
        h, w = self.shape
        out = np.zeros(self.shape, bool)
        for state, cells in self.objects:
            # rows grow backwards (-x), columns rightwards (-y)
            r = cells[:, 0] + int(np.rint(-k * state[2]))
            c = cells[:, 1] + int(np.rint(-k * state[3]))
            inside = (r >= 0) & (r < h) & (c >= 0) & (c < w)
            out[r[inside], c[inside]] = True
        return out

    def moved_to_sensor(self, image: np.ndarray, k: int) -> np.ndarray:
        """``image`` ``(H, W)`` of the last frame moved into the sensor frame ``k`` guessed
        steps on (unchanged on a still sensor): float32 in [0, 1]."""
        image = np.asarray(image)
        binary = image.dtype == np.bool_  # moved as it is, to the same numbers
        if self.motion is None:
            return image.astype(np.float32)
        moved = rigid_moved(
            image if binary else image.astype(np.float32), composed_motion(self.motion, k)
        )
        # a bool map's moved cells are sums of bilinear weights: in [0, 1] but for float64's
        # last bits above 1, which float32 rounds away, so its clip changes nothing
        return (moved if binary else np.clip(moved, 0.0, 1.0)).astype(np.float32)

    def at(self, k: int) -> np.ndarray:
        """``(H, W)`` float32, read-only: the objects ``k`` frames on (and the held cells up to
        ``hold``), in the sensor frame then."""
        if k not in self._at:
            cells = self.cells_at(k)
            if self.held is not None and k <= self.hold:
                cells = cells | self.held
            moved = self.moved_to_sensor(cells, k)
            moved.setflags(write=False)
            self._at[k] = moved
        return self._at[k]


def _wide(state: np.ndarray, cells: np.ndarray) -> bool:
    """Whether an object is the tracker's kind: a float64 state and int64 cells."""
    return getattr(state, "dtype", None) == np.float64 and getattr(cells, "dtype", None) == np.int64


@kernel
def _cells_at_loop(cells: np.ndarray, v_row: float, v_col: float, k: int, out: np.ndarray) -> bool:
    """One object of :meth:`Tracks.cells_at` into ``out`` ``(H, W)``: ``cells`` ``(N, 2)``
    shifted by the reference's ``rint(-k * v)`` (exact; the same int64 sums), those beyond the
    map dropped. ``False`` (nothing written) where a shift is not a modest integer (NaN, or
    beyond 2**31 cells), which the caller leaves to the reference."""
    h, w = out.shape
    # rows grow backwards (-x), columns rightwards (-y)
    dr, dc = np.rint(-k * v_row), np.rint(-k * v_col)
    if not (abs(dr) < 2.0**31 and abs(dc) < 2.0**31):
        return False
    shift_r, shift_c = np.int64(dr), np.int64(dc)
    for j in range(len(cells)):
        r, c = cells[j, 0] + shift_r, cells[j, 1] + shift_c
        if 0 <= r < h and 0 <= c < w:
            out[r, c] = True
    return True
