"""NumPy twins of :func:`lidarflow.ops.warp.warp` and :func:`lidarflow.ops.rigid.rigid_warp`:
a map moved by a flow, or re-expressed after the platform's own motion, for the parts of the
pipeline that run without PyTorch (the core install: the ONNX Predictor, ``evaluate``'s
baselines). Same conventions, same numbers (tests/motion/test_warp.py holds them to the torch
ops): bilinear sampling with cell centres at integers, zero outside the map.

A warp is split in two: the four corners each cell reads and their weights (``_corners``, most
of the cost), then the gathers. A rigid motion's corners are kept (a small cache by motion):
a tracker moves its background and its seen map by the same motion, and the carried objects
one frame on by that motion again (issue 46). A map with few occupied cells (the carried
objects) is moved only around them where its motion's corners are not kept. Either way the
arithmetic is the single-pass warp's, elementwise and in its order: the same numbers to the
bit.
"""

from __future__ import annotations

import threading
from collections import OrderedDict

import numpy as np

__all__ = ["rigid_moved", "warp_map"]

# Kept rigid motions' corners (640 KB each on a 100 x 100 map): a stream's motion and the
# composed motions of a roll-out of 8 steps.
_KEPT_MOTIONS = 12


def _corners(flow: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(index (4, H*W), weight (4, H*W))`` of every cell of ``flow`` ``(2, H, W)``: each cell
    reads at itself plus its flow (:func:`_corners_at`)."""
    h, w = flow.shape[1:]
    rows, cols = np.mgrid[0:h, 0:w].astype(np.float64)
    x = cols + np.asarray(flow[0], np.float64)
    y = rows + np.asarray(flow[1], np.float64)
    return _corners_at(x.ravel(), y.ravel(), h, w)


# The four corners a position reads, as rows (column, row offsets), in the warp's summing order.
_CORNER_COLS = np.array([0.0, 1.0, 0.0, 1.0])[:, None]
_CORNER_ROWS = np.array([0.0, 0.0, 1.0, 1.0])[:, None]


def _corners_at(x: np.ndarray, y: np.ndarray, h: int, w: int) -> tuple[np.ndarray, np.ndarray]:
    """``(index (4, N), weight (4, N))``: for positions ``(x, y)`` ``(N,)`` (column, row, in
    cells) on an ``(h, w)`` map, the flat index of the four cells each reads (clipped into the
    map) and their bilinear weights, zero where a corner lies outside the map. Elementwise, so
    the same numbers for a position whichever others come with it."""
    xi, yi = np.floor(x) + _CORNER_COLS, np.floor(y) + _CORNER_ROWS
    weight = (1.0 - np.abs(x - xi)) * (1.0 - np.abs(y - yi))
    inside = (xi >= 0) & (xi <= w - 1) & (yi >= 0) & (yi <= h - 1)
    index = np.clip(yi, 0, h - 1).astype(np.intp) * w + np.clip(xi, 0, w - 1).astype(np.intp)
    return index, np.where(inside, weight, 0.0)


def _sampled(
    maps: np.ndarray, corners: tuple[np.ndarray, np.ndarray], shape: tuple[int, ...]
) -> np.ndarray:
    """``maps`` ``(C, H*W)`` float64 read at ``corners``, reshaped to ``shape``."""
    index, weight = corners
    out = np.zeros(maps.shape)
    for k in range(4):
        # weight * value where the corner is inside, 0 * value = 0 outside: the single-pass
        # warp's np.where(inside, weight * value, 0), summed in its order.
        out += weight[k] * np.take(maps, index[k], axis=1)
    return out.reshape(shape)


def warp_map(image: np.ndarray, flow: np.ndarray) -> np.ndarray:
    """``out(p) = image(p + flow(p))`` ``(H, W)`` float64, bilinear, zero where ``p + flow(p)``
    falls outside the map; ``flow`` ``(2, H, W)`` in cells (column, row)."""
    image = np.asarray(image, np.float64)
    return _sampled(image.reshape(1, -1), _corners(np.asarray(flow)), image.shape)


def _rigid_flow(
    rows: np.ndarray,
    cols: np.ndarray,
    motion: tuple[float, float, float],
    h: int,
    w: int,
    res: float,
) -> np.ndarray:
    """``(2, ...)``: the flow of :func:`rigid_moved` at the cells ``(rows, cols)`` (float64),
    elementwise (so the same numbers on any subset of the map)."""
    dx, dy, yaw = motion
    x = (h - 0.5 - rows) * res
    y = (w / 2 - 0.5 - cols) * res
    cos, sin = np.cos(yaw), np.sin(yaw)
    x2, y2 = cos * x - sin * y + dx, sin * x + cos * y + dy  # new frame -> old
    return np.stack([w / 2 - 0.5 - y2 / res - cols, h - 0.5 - x2 / res - rows])


_Key = tuple[float, float, float, int, int, float]  # (dx, dy, yaw, height, width, res)


def _build_corners(key: _Key) -> tuple[np.ndarray, np.ndarray]:
    dx, dy, yaw, h, w, res = key
    rows, cols = np.mgrid[0:h, 0:w].astype(np.float64)
    index, weight = _corners(_rigid_flow(rows, cols, (dx, dy, yaw), h, w, res))
    index.setflags(write=False)  # shared by every caller of the cache
    weight.setflags(write=False)
    return index, weight


_kept: OrderedDict[_Key, tuple[np.ndarray, np.ndarray]] = OrderedDict()
_asked: OrderedDict[_Key, None] = OrderedDict()  # motions asked for once, sparse maps only
_lock = threading.Lock()  # Predictors in threads share the cache


def _rigid_corners(key: _Key, sparse: bool) -> tuple[np.ndarray, np.ndarray] | None:
    """A rigid motion's corners, kept (the last :data:`_KEPT_MOTIONS`). For a ``sparse`` map
    they are built on the motion's second use only (``None`` the first time: move it cell by
    cell): a stream whose motion changes every scan moves its carried objects by new composed
    motions every scan, and building the corners costs ~15 sparse moves."""
    with _lock:
        corners = _kept.get(key)
        if corners is not None:
            _kept.move_to_end(key)
            return corners
        if sparse and key not in _asked:
            _asked[key] = None
            while len(_asked) > 4 * _KEPT_MOTIONS:
                _asked.popitem(last=False)
            return None
    corners = _build_corners(key)
    with _lock:
        _kept[key] = corners
        while len(_kept) > _KEPT_MOTIONS:
            _kept.popitem(last=False)
    return corners


# The 5 x 5 window around a cell.
_WINDOW_ROWS, _WINDOW_COLS = (a.ravel() for a in np.mgrid[-2:3, -2:3])

# Below this share of occupied cells a map is moved cell by cell around its occupied ones.
_SPARSE_SHARE = 0.02


def _sparse_moved(image: np.ndarray, motion: tuple[float, float, float], res: float) -> np.ndarray:
    """:func:`rigid_moved` of a map with few nonzero cells ``(H, W)`` float64, computed only
    where it can be nonzero: a cell reads the four cells around where it lies in the old frame,
    so it reads an occupied cell only within sqrt(2) of where that cell lies in the new frame
    (the move is rigid). Those cells (a 5 x 5 window around each) get the warp's own
    arithmetic, elementwise, so the numbers are the dense warp's to the bit."""
    h, w = image.shape
    dx, dy, yaw = motion
    r, c = np.nonzero(image)
    x, y = (h - 0.5 - r) * res - dx, (w / 2 - 0.5 - c) * res - dy
    cos, sin = np.cos(yaw), np.sin(yaw)
    row = np.rint(h - 0.5 - (cos * x + sin * y) / res).astype(np.intp)  # old -> new: R^T (p - d)
    col = np.rint(w / 2 - 0.5 - (-sin * x + cos * y) / res).astype(np.intp)
    rows = row[:, None] + _WINDOW_ROWS
    cols = col[:, None] + _WINDOW_COLS
    inside = (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)
    cells = np.unique(rows[inside] * w + cols[inside])
    rr, cc = np.divmod(cells, w)
    flow = _rigid_flow(rr.astype(np.float64), cc.astype(np.float64), motion, h, w, res)
    index, weight = _corners_at(cc + flow[0], rr + flow[1], h, w)  # the chosen cells alone
    terms = weight * image.ravel()[index]
    values = terms[0] + terms[1]  # summed in the dense warp's order
    values += terms[2]
    values += terms[3]
    out = np.zeros(h * w)
    out[cells] = values
    return out.reshape(h, w)


def rigid_moved(image: np.ndarray, motion: np.ndarray, res: float = 1.0) -> np.ndarray:
    """``image`` ``(H, W)`` (or a stack ``(C, H, W)``, each moved alike), made in the old sensor
    frame, re-expressed in the new frame after the sensor moved by ``motion`` ``(dx, dy,
    dyaw)`` (the new frame's pose in the old one; ``dx, dy`` in the unit of ``res``: cells with
    ``res = 1``); zero where the new frame sees beyond the old grid (:mod:`lidarflow.ops.
    rigid`'s conventions). float64."""
    image = np.asarray(image, np.float64)
    h, w = image.shape[-2:]
    occupied = np.count_nonzero(image)
    if not occupied:  # nothing to move (often so for the carried objects)
        return np.zeros(image.shape)
    dx, dy, yaw = (float(v) for v in np.asarray(motion, np.float64).reshape(3))
    sparse = image.ndim == 2 and occupied <= _SPARSE_SHARE * image.size
    corners = _rigid_corners((dx, dy, yaw, h, w, float(res)), sparse)
    if corners is None:
        return _sparse_moved(image, (dx, dy, yaw), float(res))
    return _sampled(image.reshape(-1, h * w), corners, image.shape)
