"""The dynamic region of a recording, where the mover metric scores, found in hindsight over the
whole recording (for scoring only): the cells occupied at least once but in under :data:`SHARE`
of the frames that saw them, or on a simulated recording those that held a true moving object.
Counted in a world grid by the recording's poses, held in tiles of :data:`TILE` cells where
frames fall (``docs/guide/conventions.md``); a frame of unknown pose has an empty region.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from lidarflow.data.blocks import Frames
from lidarflow.data.recording import Recording
from lidarflow.scan import GridSpec, cell_centres

__all__ = [
    "SHARE",
    "TILE",
    "WorldCells",
    "dynamic_cells",
    "frame_region",
    "recording_region",
    "world_counts",
]

#: A cell is dynamic when occupied in under this share of the frames that saw it.
SHARE = 0.05

#: Cells a side of one tile of the world grid (a power of two): 6.4 m at 0.1 m, so that a
#: 10 m map covers a few tiles and a tile left mostly empty costs little (32 KiB of counts).
TILE = 64
_SHIFT = TILE.bit_length() - 1

#: Poses further than this from the origin (metres) are no place a robot drove (the Earth's
#: circumference is 4e7 m) and read as unknown: cell indices from them would lose all precision.
FARTHEST = 1e9


def dynamic_cells(occupied: np.ndarray, seen: np.ndarray, share: float = SHARE) -> np.ndarray:
    """Where ``occupied`` (frames occupied) is positive and under ``share`` of ``seen``
    (frames visible, occupied ones among them).

    >>> dynamic_cells(np.array([0, 1, 1, 20]), np.array([50, 50, 10, 20])).tolist()
    [False, True, False, False]
    """
    occupied = np.asarray(occupied)
    seen = np.asarray(seen)
    if occupied.shape != seen.shape:
        raise ValueError(f"occupied {occupied.shape} and seen {seen.shape} differ in shape")
    return (occupied > 0) & (occupied < share * seen)


class WorldCells:
    """Where each cell of a frame's map falls in a fixed world grid: flat indices ``(H, W)``
    into :attr:`size` cells, ``-1`` for a frame of unknown pose.

    ``poses`` ``(N, 3)`` ``(x, y, yaw)`` of the sensor (metres, radians; NaN unknown) or
    ``None``: the sensor frame, each cell its own. A frame's first call allocates the tiles its
    cells fall in; later calls give the same indices.
    """

    def __init__(self, grid: GridSpec, poses: np.ndarray | None, frames: int) -> None:
        self.grid, self.frames = grid, frames
        h, w, res = grid.height, grid.width, grid.res
        self._x, self._y = cell_centres(grid)
        self.poses = None if poses is None else np.asarray(poses, np.float64)
        if self.poses is not None and self.poses.shape != (frames, 3):
            raise ValueError(f"poses must be ({frames}, 3), got {self.poses.shape}")
        if self.poses is not None:
            with np.errstate(invalid="ignore"):
                far = ~(np.abs(self.poses[:, :2]) <= FARTHEST).all(axis=1)
            self.poses = np.where(far[:, None], np.nan, self.poses)
        known = None if self.poses is None else self.poses[np.isfinite(self.poses).all(axis=1)]
        self._tiles: dict[tuple[int, int], int] = {}  # tile (row, column) -> its slot
        if known is None or not len(known):
            self.poses = None
            return
        reach = float(np.hypot(h * res, w / 2 * res)) + 2 * res
        self._low = known[:, :2].min(axis=0) - reach

    @property
    def size(self) -> int:
        """The world cells allocated so far (all of them: the map's, without poses)."""
        if self.poses is None:
            return self.grid.height * self.grid.width
        return len(self._tiles) * TILE * TILE

    def __call__(self, t: int) -> np.ndarray:
        h, w = self.grid.shape
        if self.poses is None:
            return np.arange(h * w).reshape(h, w)
        px, py, yaw = self.poses[t]
        if not np.isfinite(self.poses[t]).all():
            return np.full((h, w), -1)
        c, s = np.cos(yaw), np.sin(yaw)
        wx = px + c * self._x - s * self._y
        wy = py + s * self._x + c * self._y
        i = np.floor((wx - self._low[0]) / self.grid.res).astype(np.int64)
        j = np.floor((wy - self._low[1]) / self.grid.res).astype(np.int64)
        return self._slots(i >> _SHIFT, j >> _SHIFT) * (TILE * TILE) + (
            (i & (TILE - 1)) * TILE + (j & (TILE - 1))
        )

    def _slots(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """The slot of each cell's tile (``rows``, ``cols``: tile coordinates), allocating
        the tiles not met before in the order met."""
        r0, c0 = int(rows.min()), int(cols.min())
        span = int(cols.max()) - c0 + 1
        key = (rows - r0) * span + (cols - c0)
        present = np.flatnonzero(np.bincount(key.ravel()))
        table = np.zeros(int(key.max()) + 1, np.int64)
        for k in present.tolist():
            tile = (r0 + k // span, c0 + k % span)
            table[k] = self._tiles.setdefault(tile, len(self._tiles))
        return table[key]


def world_counts(
    masks: Callable[[int], Sequence[np.ndarray]], cells: WorldCells
) -> list[np.ndarray]:
    """For each of the bool maps ``masks(t)`` gives per frame (the same number every frame),
    the number of frames in which each world cell of ``cells`` was ``True`` (flat,
    ``cells.size`` once every frame is counted)."""
    counts: list[np.ndarray] = []
    for t in range(cells.frames):
        where = cells(t)
        known = where >= 0
        if counts and len(counts[0]) < cells.size:  # new tiles: room for twice as many
            room = max(cells.size, 2 * len(counts[0]))
            counts = [np.concatenate([c, np.zeros(room - len(c), c.dtype)]) for c in counts]
        for i, mask in enumerate(masks(t)):
            if len(counts) <= i:
                counts.append(np.zeros(cells.size, np.int32))  # frames: well under 2**31
            hit = np.unique(where[known & np.asarray(mask, bool)])
            counts[i][hit] += 1
    return [c[: cells.size] for c in counts]


def frame_region(dynamic: np.ndarray, cells: WorldCells) -> Callable[[int], np.ndarray]:
    """``t -> `` frame ``t``'s region ``(H, W)`` bool from the world cells' ``dynamic`` (flat)."""

    def region(t: int) -> np.ndarray:
        where = cells(t)
        return np.where(where >= 0, dynamic[np.maximum(where, 0)], False)

    return region


def recording_region(
    recording: Recording,
    grid: GridSpec,
    occupancy: Frames,
    visibility: Frames,
    moving: Callable[[int], np.ndarray] | None = None,
) -> Callable[[int], np.ndarray]:
    """``t -> `` the dynamic region ``(H, W)`` bool of frame ``t`` of ``recording``, whose maps
    on ``grid`` are ``occupancy`` and ``visibility``; ``moving`` (``t ->`` the simulator's true
    moving cells of frame ``t``, :func:`~lidarflow.evaluate.stream.ground_truth_moving`) stands
    in for the counts where given. One pass over the maps (see the module docstring)."""
    poses = recording.extras.get("true_poses", recording.poses)
    cells = WorldCells(grid, poses, len(occupancy))
    if moving is not None:
        (held,) = world_counts(lambda t: (moving(t) & np.asarray(occupancy[t], bool),), cells)
        return frame_region(held > 0, cells)
    occupied, seen = world_counts(
        lambda t: (occupancy[t], np.asarray(visibility[t], bool) | np.asarray(occupancy[t], bool)),
        cells,
    )
    return frame_region(dynamic_cells(occupied, seen), cells)
