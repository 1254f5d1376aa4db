"""Correlative matching of two occupancy maps (Olson 2009), searched by branch and bound.

A placement is a candidate turn (:data:`YAWS`) and an index shift ``(a, b)`` (up to
:data:`MAX_SHIFT` cells each way); its score is how many of the previous map's occupied cells,
turned about the sensor into the current frame (each cell once) and shifted, land on an occupied
cell of the current map.

Branch and bound (Olson 2009, section IV): blocks of :data:`BLOCK` x :data:`BLOCK` shifts are
first scored against the current map dilated over the block, an upper bound of every shift
inside; only blocks whose bound reaches the best score so far are scored shift by shift (the
:data:`FIRST_BLOCKS` best-bounded first). Ties go to the first placement in the order turn, row
shift, column shift (shifts ``0 ... MAX_SHIFT`` before ``-MAX_SHIFT ... -1``).

Units: maps ``(H, W)`` bool; shifts in index cells; turns in radians (positive turns the world
counter-clockwise in the sensor frame of :mod:`lidarflow.geometry`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lidarflow.compiled import ready
from lidarflow.geometry import transform_cells
from lidarflow.motion.correlative_loops import correlate_loop

__all__ = ["BLOCK", "MAX_SHIFT", "YAWS", "Correlation", "correlate"]

#: Candidate turns between two frames (radians): +-4 degrees in 0.5 degree steps.
YAWS = np.deg2rad(np.linspace(-4.0, 4.0, 17))
#: Largest translation searched, cells per frame each way (12 cells: 1.2 m at 0.1 m).
MAX_SHIFT = 12
#: Side of a block of shifts bounded at once: 25 shifts a side make 5 x 5 blocks.
BLOCK = 5
#: Blocks scored shift by shift before the others are pruned by their best score.
FIRST_BLOCKS = 8

_SPAN = 2 * MAX_SHIFT + 1
_PAD = MAX_SHIFT + 1  # the shifts searched, and one more each way for the peak's neighbours
# each candidate turn as a motion (0, 0, yaw), one row per turn, for the cells in the last axis
_TURNS = np.stack([np.zeros_like(YAWS), np.zeros_like(YAWS), YAWS], axis=1)[:, None, :]
_STARTS = np.arange(-MAX_SHIFT, MAX_SHIFT + 1, BLOCK)  # each block's first shift, a side
# position of each shift in the reading order of ties (0 ... MAX_SHIFT, then -MAX_SHIFT ...)
_ORDER = np.arange(-MAX_SHIFT, MAX_SHIFT + 1) % _SPAN
# the blocks' first shifts, and every shift of each block with its reading order
_CORNERS_A, _CORNERS_B = (g.ravel() for g in np.meshgrid(_STARTS, _STARTS, indexing="ij"))
_BLOCKS = len(_CORNERS_A)
_IN_A, _IN_B = (g.ravel() for g in np.meshgrid(np.arange(BLOCK), np.arange(BLOCK), indexing="ij"))
_FINE_A, _FINE_B = _CORNERS_A[:, None] + _IN_A, _CORNERS_B[:, None] + _IN_B
_RANK = _ORDER[_FINE_A + MAX_SHIFT] * _SPAN + _ORDER[_FINE_B + MAX_SHIFT]
# each turn's cosine and sine as transform_cells takes them (one turn at a time), for the kernel
_COS = np.array([np.cos(t) for t in YAWS.tolist()])
_SIN = np.array([np.sin(t) for t in YAWS.tolist()])


@dataclass(frozen=True)
class Correlation:
    """The best placement: turn index ``k`` (into :data:`YAWS`), index shift ``(a, b)``, its
    ``score``; ``still``, the score of no motion; ``neighbours``: the scores one row shift
    before and after, one column shift before and after, and one turn before and after (the
    last two ``None`` at the ends of :data:`YAWS`), for refining the peak."""

    k: int
    a: int
    b: int
    score: int
    still: int
    neighbours: tuple[int, int, int, int, int | None, int | None]


class _Placements:
    """The current map, padded with zeros, flat, plain and dilated over a block; and the
    previous map's turned cells, one row per turn, padded with a cell that always scores 0."""

    def __init__(self, previous: np.ndarray, current: np.ndarray) -> None:
        h, w = current.shape
        self.width = w + 2 * _PAD
        # beyond the grid the map is empty; below it, rows enough that a shift of a cell in
        # their middle (the dead cell rows are padded with) never reaches the grid
        grid = np.zeros((h + 4 * _PAD + 1, self.width), np.uint8)
        grid[_PAD : _PAD + h, _PAD : _PAD + w] = current
        dilated = grid.copy()  # the largest over shifts 0 ... BLOCK - 1 down and right
        for i in range(1, BLOCK):
            np.maximum(dilated[:-i], grid[i:], out=dilated[:-i])
        down = dilated.copy()
        for j in range(1, BLOCK):
            np.maximum(dilated[:, :-j], down[:, j:], out=dilated[:, :-j])
        self.plain, self.dilated = grid.ravel(), dilated.ravel()
        dead = (h + 3 * _PAD) * self.width + _PAD

        r, c = np.nonzero(previous)
        # cells_in_new_frame(r, c, (0, 0, yaw)) for every turn at once
        cols_k, rows_k = transform_cells(c, r, _TURNS, h, w, inverse=True)
        rows_k, cols_k = np.rint(rows_k).astype(np.int64), np.rint(cols_k).astype(np.int64)
        inside = (rows_k >= 0) & (rows_k < h) & (cols_k >= 0) & (cols_k < w)
        flat = (rows_k + _PAD) * self.width + cols_k + _PAD
        size = grid.size
        # each turned cell once per turn (a raster of the turned map)
        key = np.sort((np.arange(len(YAWS))[:, None] * size + flat)[inside])
        key = key[np.r_[True, key[1:] != key[:-1]]]
        turn, flat = np.divmod(key, size)
        counts = np.bincount(turn, minlength=len(YAWS))
        first = np.cumsum(counts) - counts
        self.cells = np.full((len(YAWS), max(int(counts.max()), 1)), dead, np.int64)
        self.cells[turn, np.arange(len(key)) - first[turn]] = flat

    def offsets(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return a * self.width + b

    def scores(self, k: np.ndarray, offsets: np.ndarray, dilated: bool = False) -> np.ndarray:
        """``(len(k), S)`` scores of turns ``k`` at flat ``offsets`` ``(len(k), S)``."""
        grid = self.dilated if dilated else self.plain
        # cells last: the sum runs along contiguous memory
        return grid[offsets[:, :, None] + self.cells[k][:, None, :]].sum(axis=2)


def _best_of(
    place: _Placements, blocks: np.ndarray
) -> tuple[tuple[int, int], tuple[int, int, int]]:
    """The best placement within ``blocks`` (indices turn * blocks a turn + block), as
    ``((score, -rank), (k, a, b))``; a lower rank is read first."""
    k, m = np.divmod(blocks, len(_CORNERS_A))
    scores = place.scores(k, place.offsets(_FINE_A[m], _FINE_B[m]))
    top = int(scores.max())
    ranks = np.where(scores == top, k[:, None] * _SPAN**2 + _RANK[m], np.iinfo(np.int64).max)
    i, j = np.unravel_index(int(np.argmin(ranks)), ranks.shape)
    return (top, -int(ranks[i, j])), (int(k[i]), int(_FINE_A[m[i], j]), int(_FINE_B[m[i], j]))


def correlate(previous: np.ndarray, current: np.ndarray) -> Correlation | None:
    """The best placement of ``previous``'s occupied cells on ``current`` (both ``(H, W)``
    bool), or ``None`` where either map is empty."""
    if not previous.any() or not current.any():
        return None
    args = (previous, current, _COS, _SIN, _CORNERS_A, _CORNERS_B, _FINE_A, _FINE_B, _RANK,
            _PAD, BLOCK, FIRST_BLOCKS, _SPAN)  # fmt: skip
    if ready(correlate_loop, *args):
        k, a, b, score, still, *near = correlate_loop(*args).tolist()
    else:
        k, a, b, score, still, *near = _search(previous, current)
    inner = 0 < k < len(YAWS) - 1
    return Correlation(
        k=k,
        a=a,
        b=b,
        score=score,
        still=still,
        neighbours=(*near[:4], near[4] if inner else None, near[5] if inner else None),
    )


def _search(previous: np.ndarray, current: np.ndarray) -> list[int]:
    """The search in NumPy: ``[k, a, b, score, still, up, down, left, right, before, after]``,
    the turn's neighbours clamped to the ends of :data:`YAWS`."""
    place = _Placements(previous, current)
    corners = np.broadcast_to(place.offsets(_CORNERS_A, _CORNERS_B), (len(YAWS), _BLOCKS))
    bounds = place.scores(np.arange(len(YAWS)), corners, dilated=True).ravel().astype(np.int64)
    order = np.argsort(-bounds, kind="stable")  # signed: the counts are summed unsigned
    best, (k, a, b) = _best_of(place, order[:FIRST_BLOCKS])
    # Every other block that can still reach the best (ties too, for the reading order): the
    # best only rises, so one more round scores all that could hold it.
    rest = order[FIRST_BLOCKS:]
    rest = rest[bounds[rest] >= best[0]]
    if len(rest):
        other, placement = _best_of(place, rest)
        if other > best:
            best, (k, a, b) = other, placement
    turns = [max(k - 1, 0), min(k + 1, len(YAWS) - 1)]
    near_k = np.array([len(YAWS) // 2, k, k, k, k, *turns])
    near_a = np.array([0, a - 1, a + 1, a, a, a, a])
    near_b = np.array([0, b, b, b - 1, b + 1, b, b])
    near = place.scores(near_k, place.offsets(near_a, near_b)[:, None])[:, 0].tolist()
    return [k, a, b, best[0], *near]
