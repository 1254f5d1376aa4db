"""The compiled passes of :mod:`lidarflow.scan` (:mod:`lidarflow.compiled`): a batch of scans
into its occupancy, visibility and sub-cell maps in one pass over its beams and cells each.

Each loop does the NumPy reference's arithmetic in its order (:func:`lidarflow.scan.
_rasterize_chunk`, :func:`lidarflow.scan._return_cells`, :func:`lidarflow.scan.subcell_batch`),
so the maps are the reference's to the bit; the tests compare them. Comparisons of float32
values run in float64, which is exact: both sides are widened without rounding.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from lidarflow.beams import scan_masks
from lidarflow.compiled import kernel, ready

__all__ = ["Plan", "rasterized", "subcells"]


class Plan(NamedTuple):
    """What the passes read for one grid, beam geometry and ranges' dtype (built and cached by
    :mod:`lidarflow.scan`): the grid, each cell's beam (``index``, flat; the beam count where
    none covers it) and centre's distance (``dist``, in the ranges' dtype), the beams'
    directions, the masks' ``thresholds`` (:func:`lidarflow.beams.mask_thresholds`) and a
    no-return beam's ``reach`` (float64, exactly the dtype's value)."""

    height: int
    width: int
    res: float
    index: np.ndarray
    dist: np.ndarray
    cos: np.ndarray
    sin: np.ndarray
    thresholds: np.ndarray
    reach: float


def rasterized(r: np.ndarray, plan: Plan) -> tuple[np.ndarray, np.ndarray] | None:
    """:func:`lidarflow.scan.rasterize_batch` of ranges ``r`` ``(N, B)`` (float32 or float64,
    ``N > 0``): ``(occupancy, visibility)`` ``(N, H, W)`` bool, the reference's to the bit;
    ``None`` while the loop is not compiled yet (:func:`lidarflow.compiled.ready`)."""
    n, shape = r.shape[0], (plan.height, plan.width)
    occupancy = np.empty((n, plan.height * plan.width), dtype=bool)
    visibility = np.empty((n, plan.height * plan.width), dtype=bool)
    args = (
        r, plan.thresholds, plan.index, plan.dist, plan.cos, plan.sin, plan.reach, plan.height,
        plan.width / 2, plan.res, occupancy, visibility,
    )  # fmt: skip
    if not ready(_raster_loop, *args):
        return None
    _raster_loop(*args)
    return occupancy.reshape(n, *shape), visibility.reshape(n, *shape)


def subcells(r: np.ndarray, plan: Plan, subcell: int) -> np.ndarray | None:
    """:func:`lidarflow.scan.subcell_batch` of ranges ``r`` ``(N, B)`` (float32 or float64,
    ``N > 0``) with ``subcell`` sub-cells a side: ``(N, 2, H, W)`` bool, the reference's;
    ``None`` while the loop is not compiled yet (:func:`lidarflow.compiled.ready`)."""
    out = np.empty((r.shape[0], 2, plan.height, plan.width), dtype=bool)
    args = (r, plan.thresholds, plan.cos, plan.sin, plan.width / 2, plan.res, subcell, out)
    if not ready(_subcell_loop, *args):
        return None
    _subcell_loop(*args)
    return out


@kernel
def _beam_cell(
    rho: float, cos: float, sin: float, height: int, half_width: float, res: float
) -> tuple[float, float, float, float]:
    """A return's fractional grid coordinates ``(u, v)`` and its cell ``(row, col)`` (floats),
    as :func:`lidarflow.scan._return_cells` computes them."""
    u = height - rho * cos / res
    v = half_width - rho * sin / res
    return u, v, np.floor(u), np.floor(v)


@kernel
def _raster_loop(
    r: np.ndarray,
    thresholds: np.ndarray,
    index: np.ndarray,
    dist: np.ndarray,
    cos: np.ndarray,
    sin: np.ndarray,
    no_return_reach: float,
    height: int,
    half_width: float,
    res: float,
    occupancy: np.ndarray,
    visibility: np.ndarray,
) -> None:
    """Scans ``r`` ``(N, B)`` (their masks by ``thresholds``, :func:`lidarflow.beams.
    mask_thresholds`) into ``occupancy`` and
    ``visibility`` ``(N, H * W)`` bool (``height`` rows): a cell is visible where its centre
    (``dist``, flat, in the ranges' dtype) is nearer than its beam's (``index``; ``B``: none)
    reach, or occupied. A return reaches its range, a no-return ``no_return_reach``, any other
    beam nowhere (-1)."""
    n, beams = r.shape
    width = occupancy.shape[1] // height
    reach = np.empty(beams + 1)
    is_return, beyond = np.empty(beams, np.bool_), np.empty(beams, np.bool_)
    for s in range(n):
        scan_masks(r[s], thresholds, is_return, beyond)
        for i in range(beams):
            if is_return[i]:
                reach[i] = r[s, i]
            elif beyond[i]:
                reach[i] = no_return_reach
            else:
                reach[i] = -1.0
        reach[beams] = -1.0
        for c in range(len(dist)):
            occupancy[s, c] = False
            visibility[s, c] = dist[c] < reach[index[c]]
        for i in range(beams):
            if not is_return[i]:
                continue
            _, _, row, col = _beam_cell(
                np.float64(r[s, i]), cos[i], sin[i], height, half_width, res
            )
            if row >= 0 and row < height and col >= 0 and col < width:
                cell = int(row) * width + int(col)
                occupancy[s, cell] = True
                visibility[s, cell] = True


@kernel
def _subcell_loop(
    r: np.ndarray,
    thresholds: np.ndarray,
    cos: np.ndarray,
    sin: np.ndarray,
    half_width: float,
    res: float,
    subcell: int,
    out: np.ndarray,
) -> None:
    """:func:`lidarflow.scan.subcell_batch` of scans ``r`` ``(N, B)`` (their returns by
    ``thresholds``, :func:`lidarflow.beams.mask_thresholds`) into ``out`` ``(N, 2, H, W)``
    bool: ``edge`` where a cell holds returns and none of them deep inside (``subcell``
    sub-cells a side, the outer ring not deep), ``near`` where a return lies in the outer
    sub-cells by a neighbour's shared edge."""
    n, beams = r.shape
    height, width = out.shape[2], out.shape[3]
    last = subcell - 1
    interior = np.zeros((height, width), np.bool_)
    is_return, beyond = np.empty(beams, np.bool_), np.empty(beams, np.bool_)
    for s in range(n):
        scan_masks(r[s], thresholds, is_return, beyond)
        out[s] = False
        interior[:] = False
        for i in range(beams):
            if not is_return[i]:
                continue
            rho = np.float64(r[s, i])
            u, v, row_f, col_f = _beam_cell(rho, cos[i], sin[i], height, half_width, res)
            if not (row_f >= 0 and row_f < height and col_f >= 0 and col_f < width):
                continue
            row, col = int(row_f), int(col_f)
            sub_r = min(max(np.floor((u - row) * subcell), 0.0), last)
            sub_c = min(max(np.floor((v - col) * subcell), 0.0), last)
            out[s, 0, row, col] = True
            if sub_r > 0 and sub_r < last and sub_c > 0 and sub_c < last:
                interior[row, col] = True
            if sub_r == 0 and row > 0:
                out[s, 1, row - 1, col] = True
            if sub_r == last and row + 1 < height:
                out[s, 1, row + 1, col] = True
            if sub_c == 0 and col > 0:
                out[s, 1, row, col - 1] = True
            if sub_c == last and col + 1 < width:
                out[s, 1, row, col + 1] = True
        for row in range(height):
            for col in range(width):
                if interior[row, col]:
                    out[s, 0, row, col] = False
