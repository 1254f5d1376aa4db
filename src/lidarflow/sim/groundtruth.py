"""Exact ground-truth motion flow on the map grid (design notes, sections 2-3).

Flow is in cells: channel 0 the column displacement, channel 1 the row displacement.

* Forward flow ``F^t`` lives on the occupied cells of ``O^t``: ``O^t(p) = O^{t+1}(p + F^t(p))``.
* Backward flow ``B^t`` lives on the occupied cells of ``O^{t+1}``:
  ``O^{t+1}(p) = O^t(p + B^t(p))``.

Every return is placed exactly as :func:`lidarflow.scan.rasterize_batch` places it (so the flow
agrees with the occupancy), moved in the world with the object its beam hit (a leg; static
structure does not move), seen from the other frame's sensor pose, and turned into a displacement
in cells. A cell gets the mean of its points' displacements; cells not occupied carry zero flow.
"""

from __future__ import annotations

import numpy as np

from lidarflow.beams import RETURN, beam_status
from lidarflow.scan import BeamGeometry, GridSpec
from lidarflow.sim.lidar import STATIC_ID

__all__ = ["MOVING_THRESHOLD", "ground_truth"]

#: A point is on a moving object when the object moves more than this (m) to the next frame.
MOVING_THRESHOLD = 0.01


def _points(ranges: np.ndarray, geometry: BeamGeometry, grid: GridSpec) -> tuple[np.ndarray, ...]:
    """Returns of ``(n, B)`` ranges placed like the rasterizer does: frame, beam, x, y (m, sensor
    frame) and flat cell index, for the returns that land inside the grid."""
    # the rasterizer's rule, in the stored dtype (a reading at range_max is no return)
    ret = beam_status(np.asarray(ranges), geometry.range_min, geometry.range_max) == RETURN
    r = np.asarray(ranges).astype(np.float64)
    f, b = np.nonzero(ret)
    angles = geometry.angles
    rho = r[f, b]
    px = rho * np.cos(angles)[b]
    py = rho * np.sin(angles)[b]
    height, width = grid.shape
    row = np.floor(height - px / grid.res).astype(np.int64)
    col = np.floor(width / 2 - py / grid.res).astype(np.int64)
    inside = (row >= 0) & (row < height) & (col >= 0) & (col < width)
    return f[inside], b[inside], px[inside], py[inside], (row * width + col)[inside]


def _to_frame(
    f: np.ndarray, wx: np.ndarray, wy: np.ndarray, poses: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """World points seen from ``poses[f]``: sensor-frame ``(x, y)``."""
    c, s = np.cos(poses[:, 2])[f], np.sin(poses[:, 2])[f]
    dx, dy = wx - poses[f, 0], wy - poses[f, 1]
    return c * dx + s * dy, -s * dx + c * dy


def _flow(
    px: np.ndarray,
    py: np.ndarray,
    wx: np.ndarray,
    wy: np.ndarray,
    step: np.ndarray,
    f_dst: np.ndarray,
    poses: np.ndarray,
    res: float,
) -> np.ndarray:
    """``(K, 2)`` flow in cells of points at sensor ``(px, py)`` / world ``(wx, wy)`` that move
    by ``step (K, 2)`` in the world and are then seen from ``poses[f_dst]``."""
    qx, qy = _to_frame(f_dst, wx + step[:, 0], wy + step[:, 1], poses)
    # Column index grows towards -y, row index towards -x.
    return np.column_stack([(py - qy) / res, (px - qx) / res])


def _cell_mean(
    out: np.ndarray, f: np.ndarray, cell: np.ndarray, flow: np.ndarray, grid: GridSpec
) -> None:
    """Write the mean flow of the points in each cell into ``out (n, 2, H, W)`` (zeros
    elsewhere are left as they are)."""
    size = grid.height * grid.width
    cells, inverse, count = np.unique(f * size + cell, return_inverse=True, return_counts=True)
    frame, flat = np.divmod(cells, size)
    row, col = np.divmod(flat, grid.width)
    for ch in range(2):
        out[frame, ch, row, col] = np.bincount(inverse, weights=flow[:, ch]) / count


def ground_truth(
    ranges: np.ndarray,
    ids: np.ndarray,
    poses: np.ndarray,
    objects: np.ndarray,
    geometry: BeamGeometry,
    grid: GridSpec,
    out: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ground truth for frames ``0..n-1`` of a block of ``n + 1`` consecutive frames.

    Args:
        ranges: ``(n + 1, B)`` measured ranges (the values stored in the recording).
        ids: ``(n + 1, B)`` id of the object each beam hit (``lidar.cast_rays``).
        poses: ``(n + 1, 3)`` true sensor poses ``(x, y, yaw)``, world frame.
        objects: ``(n + 1, L, 2)`` world positions of the dynamic objects (NaN when absent).
        geometry, grid: the beams and the map grid.
        out: optional zero-filled ``(backward, forward, moving)`` arrays to fill in place (any
            float dtype for the flows, float16 in recordings); only occupied cells are written.

    Returns:
        ``(backward, forward, moving)`` (``out`` when given): ``(n, 2, H, W)`` float32
        ``B^t`` and ``F^t`` in cells (channel 0 column, 1 row), and ``(n, H, W)`` bool, the
        cells of ``O^t`` hit on an object that moves more than :data:`MOVING_THRESHOLD` to frame
        ``t + 1``.
    """
    n = len(ranges) - 1
    if out is None:
        shape = (n, 2, grid.height, grid.width)
        out = (
            np.zeros(shape, np.float32),
            np.zeros(shape, np.float32),
            np.zeros((n, grid.height, grid.width), bool),
        )
    backward, forward, moving = out
    # Every return of the n + 1 scans, once: sensor frame, world frame, object hit.
    f, b, px, py, cell = _points(ranges, geometry, grid)
    c, s = np.cos(poses[:, 2])[f], np.sin(poses[:, 2])[f]
    wx = poses[f, 0] + c * px - s * py
    wy = poses[f, 1] + s * px + c * py
    obj = ids[f, b]
    motion = objects[1:] - objects[:-1]  # (n, L, 2): frame t -> t + 1
    motion = np.where(np.isfinite(motion), motion, 0.0)  # an object that is gone does not move
    dynamic = obj > STATIC_ID

    # Forward: points of scan t < n, moved t -> t + 1, seen from t + 1.
    sel = f < n
    step = np.zeros((int(sel.sum()), 2))
    dyn = dynamic[sel]
    step[dyn] = motion[f[sel][dyn], obj[sel][dyn]]
    fw = _flow(px[sel], py[sel], wx[sel], wy[sel], step, f[sel] + 1, poses, grid.res)
    _cell_mean(forward, f[sel], cell[sel], fw, grid)
    on = np.hypot(step[:, 0], step[:, 1]) > MOVING_THRESHOLD
    moving[f[sel][on], *np.divmod(cell[sel][on], grid.width)] = True

    # Backward: points of scan t + 1, moved back t + 1 -> t, seen from t; stored at index t.
    sel = f > 0
    step = np.zeros((int(sel.sum()), 2))
    dyn = dynamic[sel]
    step[dyn] = -motion[f[sel][dyn] - 1, obj[sel][dyn]]
    bw = _flow(px[sel], py[sel], wx[sel], wy[sel], step, f[sel] - 1, poses, grid.res)
    _cell_mean(backward, f[sel] - 1, cell[sel], bw, grid)
    return backward, forward, moving
