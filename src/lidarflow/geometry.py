"""The grid's geometry in NumPy: cells and the sensor frame, rigid moves, bilinear sampling.

Grid convention (design notes section 2; sensor frame, REP 103): cell ``(r, c)`` of an ``H x W``
grid of cell size ``res`` has its centre at ``x = (H - 0.5 - r) * res`` forward and
``y = (W / 2 - 0.5 - c) * res`` to the left; row 0 is the far edge, column 0 the left edge, the
sensor sits at the middle of the bottom edge. Cell coordinates are continuous: integers are
cell centres.

Motion convention: ``motion = (dx, dy, dyaw)`` is the pose of the *new* sensor frame in the
*old* one (the odometry increment): the sensor moved ``dx`` forward and ``dy`` left (in the unit
of ``res``: cells with ``res = 1``) and turned ``dyaw`` radians counter-clockwise. A point ``q``
of the new frame is ``R(dyaw) q + (dx, dy)`` in the old one; a point ``p`` of the old frame is
``R(dyaw)^T (p - (dx, dy))`` in the new one. :func:`lidarflow.ops.rigid.transform_cells` is the
same in torch (tests/test_geometry.py holds the two to the same numbers).

Sampling convention (:func:`lidarflow.ops.warp.warp`'s): bilinear between the four cells around
a position, zero where one of them lies outside the grid. A :class:`Sampler` keeps, for every
cell, the four cells it reads and their weights, so sampling ``C`` maps is four gathers. The
samplers of rigid moves are kept by motion, process-wide (:func:`rigid_sampler`): a stream moves
its state, its next map, its background and its tracked objects by one motion, and a roll-out
assumes the same motion at every step.

>>> x, y = cell_to_metric(np.array([9]), np.array([5]), 10, 10, res=0.1)  # nearest the sensor
>>> x.round(6).tolist(), y.round(6).tolist()
([0.05], [-0.05])
"""

from __future__ import annotations

import threading
from collections import OrderedDict

import numpy as np

__all__ = [
    "TOLERANCE",
    "FlowWarp",
    "Sampler",
    "cell_to_metric",
    "metric_to_cell",
    "near",
    "rigid_moved",
    "rigid_positions",
    "rigid_sampler",
    "transform_cells",
    "warp_map",
]

_Scalars = float | np.ndarray


def cell_to_metric(
    rows: np.ndarray, cols: np.ndarray, height: int, width: int, res: float = 1.0
) -> tuple[np.ndarray, np.ndarray]:
    """``(x, y)`` in the sensor frame (units of ``res``) of cell coordinates ``rows, cols``
    (any broadcastable shapes) of a ``height x width`` grid; float64.

    >>> cell_to_metric(np.array([0, 3]), np.array([0, 1]), 4, 2)
    (array([3.5, 0.5]), array([ 0.5, -0.5]))
    """
    x, y = height - 0.5 - rows, width / 2 - 0.5 - cols
    if res == 1.0:  # the same numbers: multiplying by 1 is exact
        return x, y
    return x * res, y * res


def metric_to_cell(
    x: np.ndarray, y: np.ndarray, height: int, width: int, res: float = 1.0
) -> tuple[np.ndarray, np.ndarray]:
    """``(rows, cols)``, continuous, of sensor-frame points ``(x, y)``: the inverse of
    :func:`cell_to_metric` (the nearest cell is ``np.rint`` of them).

    >>> metric_to_cell(np.array([3.5]), np.array([-0.5]), 4, 2)
    (array([0.]), array([1.]))
    """
    if res != 1.0:  # dividing by 1 is exact
        x, y = x / res, y / res
    return height - 0.5 - x, width / 2 - 0.5 - y


def _motion_parts(motion: np.ndarray) -> tuple[_Scalars, _Scalars, _Scalars]:
    """``(dx, dy, dyaw)``: Python floats for one motion (3 values), arrays ``(...)`` for
    motions ``(..., 3)``."""
    m = np.asarray(motion, np.float64)
    if m.ndim <= 1:
        if m.size != 3:
            raise ValueError(f"motion must be (dx, dy, dyaw), got shape {m.shape}")
        dx, dy, yaw = (float(v) for v in m.reshape(3))
        return dx, dy, yaw
    if m.shape[-1] != 3:
        raise ValueError(f"motions must be (..., 3) (dx, dy, dyaw), got shape {m.shape}")
    return m[..., 0], m[..., 1], m[..., 2]


def _cos_sin(yaw: _Scalars) -> tuple[_Scalars, _Scalars]:
    """``cos`` and ``sin`` of each turn, each taken alone: motions given together move cells
    to the bit as each given alone does."""
    if isinstance(yaw, float):
        return np.cos(yaw), np.sin(yaw)
    turns = yaw.ravel().tolist()
    cos = np.array([np.cos(t) for t in turns]).reshape(yaw.shape)
    sin = np.array([np.sin(t) for t in turns]).reshape(yaw.shape)
    return cos, sin


def transform_cells(
    cols: np.ndarray,
    rows: np.ndarray,
    motion: np.ndarray,
    height: int,
    width: int,
    res: float = 1.0,
    inverse: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """Move cell coordinates ``(cols, rows)`` of a ``height x width`` grid from the new frame to
    the old one (``R q + d``) after the sensor moved by ``motion`` (``dx, dy`` in the unit of
    ``res``); ``inverse``: from the old frame to the new one (``R^T (p - d)``). Returns the
    ``(cols, rows)`` of the same points in the other frame, continuous, float64.

    ``motion`` is one ``(dx, dy, dyaw)`` or motions ``(..., 3)`` broadcast against the cells.

    >>> c, r = transform_cells(np.array([1.0]), np.array([3.0]), np.array([2.0, 0, 0]), 4, 2)
    >>> c.tolist(), r.tolist()  # 2 cells forward: the old frame saw it 2 rows further away
    ([1.0], [1.0])
    """
    dx, dy, yaw = _motion_parts(motion)
    x, y = cell_to_metric(rows, cols, height, width, res)
    cos, sin = _cos_sin(yaw)
    if inverse:  # old -> new: R^T (p - d)
        x, y = x - dx, y - dy
        x2, y2 = cos * x + sin * y, -sin * x + cos * y
    else:  # new -> old: R q + d
        x2, y2 = cos * x - sin * y + dx, sin * x + cos * y + dy
    rows2, cols2 = metric_to_cell(x2, y2, height, width, res)
    return cols2, rows2


def rigid_positions(
    motion: np.ndarray, height: int, width: int, res: float = 1.0, inverse: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """``(cols, rows)`` ``(H, W)``: where each cell of the new frame lies in the old one after
    the sensor moved by ``motion`` (:func:`transform_cells` of every cell); ``inverse``: where
    each cell of the old frame lies in the new one.

    >>> c, r = rigid_positions(np.array([1.0, 0.0, 0.0]), 3, 2)
    >>> r[:, 0].tolist()  # one cell forward: each row reads one row further away
    [-1.0, 0.0, 1.0]
    """
    rows, cols = np.indices((height, width), dtype=np.float64)
    return transform_cells(cols, rows, motion, height, width, res, inverse)


# The four corners a position reads, as rows (column, row offsets), in the summing order.
_CORNER_COLS = np.array([0.0, 1.0, 0.0, 1.0])[:, None]
_CORNER_ROWS = np.array([0.0, 0.0, 1.0, 1.0])[:, None]


def _corners(x: np.ndarray, y: np.ndarray, h: int, w: int) -> tuple[np.ndarray, np.ndarray]:
    """``(index (4, N), weight (4, N))``: for positions ``(x, y)`` ``(N,)`` (column, row) on an
    ``(h, w)`` map, the flat index of the four cells each reads (clipped into the map) and their
    bilinear weights, zero where a corner lies outside the map. Elementwise: the same numbers
    for a position whichever others come with it."""
    xi, yi = np.floor(x) + _CORNER_COLS, np.floor(y) + _CORNER_ROWS
    weight = (1.0 - np.abs(x - xi)) * (1.0 - np.abs(y - yi))
    inside = (xi >= 0) & (xi <= w - 1) & (yi >= 0) & (yi <= h - 1)
    index = np.clip(yi, 0, h - 1).astype(np.intp) * w + np.clip(xi, 0, w - 1).astype(np.intp)
    return index, np.where(inside, weight, 0.0)


def _gathered(flat: np.ndarray, index: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """``flat`` ``(C, H*W)`` read at the corners ``index, weight`` ``(4, N)``: ``(C, N)``, the
    four weighted corners summed in their order, in ``flat``'s precision."""
    # np.take, in place: twice as fast as fancy indexing along the second axis.
    out = np.take(flat, index[0], axis=1)
    out *= weight[0]
    for k in range(1, 4):
        corner = np.take(flat, index[k], axis=1)
        corner *= weight[k]
        out += corner
    return out


class Sampler:
    """Samples maps ``(..., H, W)`` at fixed positions ``cols, rows`` ``(H, W)`` (in cells),
    bilinear, zero where a position's corner lies outside the map; float32 maps in float32
    (``grid_sample``'s arithmetic), any other in float64. Read-only once built: one sampler
    may serve several threads.

    >>> s = Sampler(np.full((2, 3), 0.5), np.zeros((2, 3)))  # half a cell right of each column 0
    >>> s(np.arange(6.0).reshape(2, 3))[0].tolist()
    [0.5, 0.5, 0.5]
    """

    def __init__(self, cols: np.ndarray, rows: np.ndarray) -> None:
        cols, rows = np.asarray(cols, np.float64), np.asarray(rows, np.float64)
        if cols.shape != rows.shape or cols.ndim != 2:
            raise ValueError(f"cols and rows must be one (H, W), got {cols.shape}, {rows.shape}")
        self.shape: tuple[int, int] = (int(cols.shape[0]), int(cols.shape[1]))
        self._index, self._weight = _corners(cols.ravel(), rows.ravel(), *self.shape)
        self._index.setflags(write=False)
        self._weight.setflags(write=False)
        self._weight32: np.ndarray | None = None

    @classmethod
    def from_flow(cls, flow: np.ndarray) -> Sampler:
        """The sampler of :func:`lidarflow.ops.warp.warp`'s ``flow`` ``(2, H, W)`` (cells,
        column then row): each cell reads at itself plus its flow."""
        flow = np.asarray(flow, np.float64)
        if flow.ndim != 3 or flow.shape[0] != 2:
            raise ValueError(f"flow must be (2, H, W), got {flow.shape}")
        rows, cols = np.indices(flow.shape[1:], dtype=np.float64)
        return cls(cols + flow[0], rows + flow[1])

    def __call__(self, maps: np.ndarray) -> np.ndarray:
        """``maps`` ``(..., H, W)`` sampled, float32 for float32 maps, else float64."""
        maps = np.asarray(maps)
        if maps.ndim < 2 or maps.shape[-2:] != self.shape:
            h, w = self.shape
            raise ValueError(f"maps must be (..., {h}, {w}), got {maps.shape}")
        if maps.dtype == np.float32:
            if self._weight32 is None:  # a benign race: every thread computes the same
                weight32 = self._weight.astype(np.float32)
                weight32.setflags(write=False)
                self._weight32 = weight32
            weight = self._weight32
        else:
            maps, weight = maps.astype(np.float64, copy=False), self._weight
        flat = maps.reshape(-1, maps.shape[-2] * maps.shape[-1])
        return _gathered(flat, self._index, weight).reshape(maps.shape)

    def adjoint(self, grads: np.ndarray) -> np.ndarray:
        """The transpose of this sampling, float64: ``grads`` ``(H, W)`` on a sampled map ->
        the gradient on the map it was sampled from (each cell gets the weighted sum of the
        grads of the positions that read it)."""
        grads = np.asarray(grads, np.float64)
        if grads.shape != self.shape:
            raise ValueError(f"grads must be {self.shape}, got {grads.shape}")
        spread = self._weight * grads.reshape(1, -1)
        total = np.bincount(self._index.ravel(), spread.ravel(), grads.size)
        return total.reshape(self.shape)


def warp_map(image: np.ndarray, flow: np.ndarray) -> np.ndarray:
    """``out(p) = image(p + flow(p))`` ``(H, W)`` float64, bilinear, zero where ``p + flow(p)``
    falls outside the map; ``flow`` ``(2, H, W)`` in cells (column, row): the NumPy
    :func:`lidarflow.ops.warp.warp`.

    >>> warp_map(np.arange(4.0).reshape(2, 2), np.full((2, 2, 2), 0.5))[0, 0].item()
    1.5
    """
    return Sampler.from_flow(flow)(np.asarray(image, np.float64))


class FlowWarp:
    """:func:`warp_map` with the sampler of the last flow kept: a roll-out moves every fed-back
    map by the same flow where the model's flow is the platform's motion alone (comparing the
    flow costs a tenth of building the sampler). One per stream (not shared between threads)."""

    def __init__(self) -> None:
        self._flow: np.ndarray | None = None
        self._sampler: Sampler | None = None

    def __call__(self, image: np.ndarray, flow: np.ndarray) -> np.ndarray:
        """``image`` ``(H, W)`` sampled at each cell plus ``flow`` ``(2, H, W)``, float64."""
        if self._sampler is None or self._flow is None or not np.array_equal(flow, self._flow):
            self._flow = np.array(flow, copy=True)
            self._sampler = Sampler.from_flow(self._flow)
        return self._sampler(np.asarray(image, np.float64))


# Kept rigid samplers (640 KB each on a 100 x 100 map, 800 KB once used on float32): a stream's
# motion and next motion, and the composed motions of a roll-out of 8 steps.
_KEPT_MOTIONS = 16
_Key = tuple[float, float, float, int, int, float]  # (dx, dy, dyaw, height, width, res)
_kept: OrderedDict[_Key, Sampler] = OrderedDict()
_asked: OrderedDict[_Key, None] = OrderedDict()  # motions asked for once, sparse maps only
_lock = threading.Lock()  # Predictors in threads share the samplers


def _kept_sampler(key: _Key, sparse: bool = False) -> Sampler | None:
    """The sampler of a rigid motion, kept (the last :data:`_KEPT_MOTIONS`). For a ``sparse``
    map it is built on the motion's second use only (``None`` the first time: move it cell by
    cell): a stream whose motion changes every scan moves its carried objects by new composed
    motions every scan, and building a sampler costs ~15 sparse moves."""
    with _lock:
        sampler = _kept.get(key)
        if sampler is not None:
            _kept.move_to_end(key)
            return sampler
        if sparse and key not in _asked:
            _asked[key] = None
            while len(_asked) > 4 * _KEPT_MOTIONS:
                _asked.popitem(last=False)
            return None
    dx, dy, yaw, h, w, res = key
    sampler = Sampler(*rigid_positions(np.array([dx, dy, yaw]), h, w, res))
    with _lock:
        _kept[key] = sampler
        while len(_kept) > _KEPT_MOTIONS:
            _kept.popitem(last=False)
    return sampler


def _key(motion: np.ndarray, height: int, width: int, res: float) -> _Key:
    dx, dy, yaw = (float(v) for v in np.asarray(motion, np.float64).reshape(3))
    return dx, dy, yaw, int(height), int(width), float(res)


def rigid_sampler(motion: np.ndarray, height: int, width: int, res: float = 1.0) -> Sampler:
    """The sampler that re-expresses ``height x width`` maps made in the old sensor frame in the
    new one after the sensor moved by ``motion`` (``out(p)`` = the old map at
    :func:`transform_cells` of ``p``), kept process-wide by motion: the NumPy
    :func:`lidarflow.ops.rigid.rigid_warp`."""
    sampler = _kept_sampler(_key(motion, height, width, res))
    if sampler is None:  # only a sparse map's first ask goes without
        raise RuntimeError("a rigid sampler asked for a dense use was not built")
    return sampler


# The 5 x 5 window around a cell.
_WINDOW_ROWS, _WINDOW_COLS = (a.ravel() for a in np.mgrid[-2:3, -2:3])

# Below this share of occupied cells a map is moved cell by cell around its occupied ones.
_SPARSE_SHARE = 0.02


def _sparse_moved(image: np.ndarray, key: _Key) -> np.ndarray:
    """:func:`rigid_moved` of a map ``(H, W)`` float64 with few nonzero cells, computed only
    where it can be nonzero: a cell reads the four cells around where it lies in the old frame,
    so it reads a nonzero cell only within sqrt(2) of where that cell lies in the new frame
    (the move is rigid). Those cells (a 5 x 5 window around each) get the sampler's own
    arithmetic, elementwise: the numbers of the whole map's sampler to the bit."""
    h, w = image.shape
    motion, res = np.array(key[:3]), key[5]
    r, c = np.nonzero(image)
    col, row = (np.rint(v).astype(np.intp) for v in transform_cells(c, r, motion, h, w, res, True))
    rows = row[:, None] + _WINDOW_ROWS
    cols = col[:, None] + _WINDOW_COLS
    inside = (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)
    cells = np.unique(rows[inside] * w + cols[inside])
    rr, cc = np.divmod(cells, w)
    x, y = transform_cells(cc.astype(np.float64), rr.astype(np.float64), motion, h, w, res)
    out = np.zeros(h * w)
    out[cells] = _gathered(image.reshape(1, -1), *_corners(x, y, h, w))[0]
    return out.reshape(h, w)


def rigid_moved(image: np.ndarray, motion: np.ndarray, res: float = 1.0) -> np.ndarray:
    """``image`` ``(H, W)`` (or a stack ``(..., H, W)``, each moved alike), made in the old
    sensor frame, re-expressed in the new frame after the sensor moved by ``motion``
    (:func:`rigid_sampler`'s numbers); zero where the new frame sees beyond the old grid.
    float64. A map with few nonzero cells is moved around them alone the first time its
    motion comes (the same numbers).

    >>> image = np.zeros((5, 4))
    >>> image[1, 1] = 1.0
    >>> np.argwhere(rigid_moved(image, np.array([1.0, 0.0, 0.0]))).tolist()  # 1 row closer
    [[2, 1]]
    """
    image = np.asarray(image, np.float64)
    h, w = image.shape[-2:]
    occupied = np.count_nonzero(image)
    if not occupied:  # nothing to move (often so for the carried objects)
        return np.zeros(image.shape)
    key = _key(motion, h, w, res)
    sparse = image.ndim == 2 and occupied <= _SPARSE_SHARE * image.size
    sampler = _kept_sampler(key, sparse)
    if sampler is None:
        return _sparse_moved(image, key)
    return sampler(image)


#: Cells within which a prediction counts as near a true cell (Euclidean), as the mover
#: metric and the online combination count: 0.2 m on the default grid.
TOLERANCE = 2


def _disc(radius: int) -> list[tuple[int, int]]:
    return [
        (dr, dc)
        for dr in range(-radius, radius + 1)
        for dc in range(-radius, radius + 1)
        if dr * dr + dc * dc <= radius * radius
    ]


def near(mask: np.ndarray, radius: int = TOLERANCE) -> np.ndarray:
    """The cells of ``(..., H, W)`` bool ``mask`` dilated by a Euclidean disc of ``radius``
    cells: ``True`` where a ``True`` cell of ``mask`` lies within ``radius`` cells.

    >>> near(np.eye(1, 5, 2, dtype=bool), 1).astype(int)
    array([[0, 1, 1, 1, 0]])
    """
    mask = np.asarray(mask, bool)
    if mask.ndim < 2:
        raise ValueError(f"mask must be (..., H, W), got {mask.shape}")
    if radius < 0:
        raise ValueError(f"radius must be >= 0, got {radius}")
    h, w = mask.shape[-2:]
    out = mask.copy()
    for dr, dc in _disc(radius):
        if (dr, dc) == (0, 0) or abs(dr) >= h or abs(dc) >= w:
            continue
        # out[r, c] |= mask[r + dr, c + dc] where that cell exists
        out[..., max(0, -dr) : h - max(0, dr), max(0, -dc) : w - max(0, dc)] |= mask[
            ..., max(0, dr) : h - max(0, -dr), max(0, dc) : w - max(0, -dc)
        ]
    return out
