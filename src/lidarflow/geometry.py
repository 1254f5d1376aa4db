"""The grid's geometry in NumPy: cells and the sensor frame, rigid moves, bilinear sampling.

Grid (design notes section 2, REP 103): cell ``(r, c)`` of an ``H x W`` grid of cell size
``res`` has its centre at ``x = (H - 0.5 - r) * res`` forward, ``y = (W / 2 - 0.5 - c) * res``
left; cell coordinates are continuous, integers are cell centres.

Motion: ``motion = (dx, dy, dyaw)`` is the pose of the *new* sensor frame in the *old* one
(``dx, dy`` in the unit of ``res``, ``dyaw`` radians counter-clockwise): a point ``q`` of the new
frame is ``R(dyaw) q + (dx, dy)`` in the old one. :mod:`lidarflow.ops.rigid` is the same in torch.

Sampling (:func:`lidarflow.ops.warp.warp`'s): bilinear between the four cells around a position,
zero where one lies outside the grid. Rigid samplers are kept process-wide by motion
(:func:`rigid_sampler`): a stream moves several maps by one motion.

>>> x, y = cell_to_metric(np.array([9]), np.array([5]), 10, 10, res=0.1)  # nearest the sensor
>>> x.round(6).tolist(), y.round(6).tolist()
([0.05], [-0.05])
"""

from __future__ import annotations

import threading
from collections import OrderedDict

import numpy as np

from lidarflow.compiled import kernel, ready

__all__ = [
    "FlowWarp",
    "Sampler",
    "cell_to_metric",
    "metric_to_cell",
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
    return (height - 0.5 - rows) * res, (width / 2 - 0.5 - cols) * res


def metric_to_cell(
    x: np.ndarray, y: np.ndarray, height: int, width: int, res: float = 1.0
) -> tuple[np.ndarray, np.ndarray]:
    """``(rows, cols)``, continuous, of sensor-frame points ``(x, y)``: the inverse of
    :func:`cell_to_metric` (the nearest cell is ``np.rint`` of them).

    >>> metric_to_cell(np.array([3.5]), np.array([-0.5]), 4, 2)
    (array([0.]), array([1.]))
    """
    return height - 0.5 - x / res, width / 2 - 0.5 - y / res


def _motion_parts(motion: np.ndarray) -> tuple[_Scalars, _Scalars, _Scalars]:
    """``(dx, dy, dyaw)``: floats for one motion, arrays ``(...)`` for motions ``(..., 3)``."""
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
    """``cos`` and ``sin`` of each turn taken alone: motions given together then move cells to
    the bit as each given alone does."""
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
    """Cell coordinates ``(cols, rows)`` moved from the new frame to the old one (``R q + d``);
    ``inverse``: from the old frame to the new one (``R^T (p - d)``). ``motion`` is one
    ``(dx, dy, dyaw)`` or motions ``(..., 3)`` broadcast against the cells. float64.

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
    """``(cols, rows)`` ``(H, W)``: :func:`transform_cells` of every cell.

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
    """``(index (4, N), weight (4, N))``: the flat index of the four cells each position
    ``(x, y)`` ``(N,)`` reads on an ``(h, w)`` map (clipped into it) and their bilinear weights,
    zero outside the map. Elementwise: a position's numbers do not depend on the others."""
    x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
    index, weight = np.empty((4, len(x)), np.intp), np.empty((4, len(x)))
    if ready(_corners_loop, x, y, h, w, index, weight):
        _corners_loop(x, y, h, w, index, weight)
        return index, weight
    xi, yi = np.floor(x) + _CORNER_COLS, np.floor(y) + _CORNER_ROWS
    weight = (1.0 - np.abs(x - xi)) * (1.0 - np.abs(y - yi))
    inside = (xi >= 0) & (xi <= w - 1) & (yi >= 0) & (yi <= h - 1)
    index = np.clip(yi, 0, h - 1).astype(np.intp) * w + np.clip(xi, 0, w - 1).astype(np.intp)
    return index, np.where(inside, weight, 0.0)


@kernel
def _corners_loop(
    x: np.ndarray, y: np.ndarray, h: int, w: int, index: np.ndarray, weight: np.ndarray
) -> None:
    """:func:`_corners` into ``index, weight`` ``(4, N)``, one pass (the same arithmetic)."""
    for i in range(len(x)):
        fx, fy = np.floor(x[i]), np.floor(y[i])
        for k in range(4):
            xi, yi = fx + (k % 2), fy + (k // 2)  # _CORNER_COLS, _CORNER_ROWS
            inside = xi >= 0 and xi <= w - 1 and yi >= 0 and yi <= h - 1
            row, col = min(max(yi, 0.0), h - 1.0), min(max(xi, 0.0), w - 1.0)
            index[k, i] = np.intp(row) * w + np.intp(col)
            weight[k, i] = (1.0 - abs(x[i] - xi)) * (1.0 - abs(y[i] - yi)) if inside else 0.0


@kernel
def _gather_loop(flat: np.ndarray, index: np.ndarray, weight: np.ndarray, out: np.ndarray) -> None:
    """:func:`_gathered_numpy` into ``out`` ``(C, N)``, one pass (the same sums, in order)."""
    for j in range(out.shape[0]):
        for i in range(out.shape[1]):
            acc = flat[j, index[0, i]] * weight[0, i]
            for k in range(1, 4):
                acc += flat[j, index[k, i]] * weight[k, i]
            out[j, i] = acc


def _gathered(flat: np.ndarray, index: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """``flat`` ``(C, H*W)`` read at the corners ``index, weight`` ``(4, N)``: ``(C, N)``, the
    weighted corners summed in their order, in the precision of ``flat`` times ``weight`` (a
    bool map's sums are the same as its float64 copy's: a corner adds its weight or 0)."""
    out = np.empty((flat.shape[0], index.shape[1]), np.result_type(flat, weight))
    flat = np.ascontiguousarray(flat)
    if not ready(_gather_loop, flat, index, weight, out, variant=flat.dtype.char):
        return _gathered_numpy(flat, index, weight)
    _gather_loop(flat, index, weight, out)
    return out


def _exact(maps: np.ndarray) -> np.ndarray:
    """``maps`` as sampled in float64: a bool map as it is (its sums are its float64 copy's,
    each corner adding its weight or nothing), any other as float64."""
    return maps if maps.dtype == np.bool_ else maps.astype(np.float64, copy=False)


def _gathered_numpy(flat: np.ndarray, index: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """:func:`_gathered` in NumPy (the reference)."""
    # np.take: faster than fancy indexing along the second axis; a bool map's corners are
    # gathered as bytes, an eighth of its float64 copy's
    out = np.multiply(np.take(flat, index[0], axis=1), weight[0])
    corner = np.empty_like(out)
    for k in range(1, 4):
        np.multiply(np.take(flat, index[k], axis=1), weight[k], out=corner)
        out += corner
    return out


class Sampler:
    """Samples maps ``(..., H, W)`` at fixed positions ``cols, rows`` ``(H, W)`` (cells),
    bilinear, zero outside the map; float32 maps in float32 (``grid_sample``'s arithmetic),
    any other in float64. Read-only once built, so threads may share one.

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
        """Each cell reads at itself plus ``flow`` ``(2, H, W)`` (cells, column then row)."""
        flow = np.asarray(flow, np.float64)
        if flow.ndim != 3 or flow.shape[0] != 2:
            raise ValueError(f"flow must be (2, H, W), got {flow.shape}")
        rows, cols = np.indices(flow.shape[1:], dtype=np.float64)
        return cls(cols + flow[0], rows + flow[1])

    def __call__(self, maps: np.ndarray) -> np.ndarray:
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
            maps, weight = _exact(maps), self._weight
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
    """The NumPy :func:`lidarflow.ops.warp.warp`: ``out(p) = image(p + flow(p))`` ``(H, W)``,
    float64; ``flow`` ``(2, H, W)`` in cells (column, row).

    >>> warp_map(np.arange(4.0).reshape(2, 2), np.full((2, 2, 2), 0.5))[0, 0].item()
    1.5
    """
    return Sampler.from_flow(flow)(np.asarray(image, np.float64))


class FlowWarp:
    """:func:`warp_map` keeping the sampler of the last flow (a roll-out moves every fed-back
    map by the same flow where it is the platform's motion alone). One per stream, not shared
    between threads."""

    def __init__(self) -> None:
        self._flow: np.ndarray | None = None
        self._sampler: Sampler | None = None

    def __call__(self, image: np.ndarray, flow: np.ndarray) -> np.ndarray:
        if self._sampler is None or self._flow is None or not np.array_equal(flow, self._flow):
            self._flow = np.array(flow, copy=True)
            self._sampler = Sampler.from_flow(self._flow)
        return self._sampler(np.asarray(image, np.float64))


# Kept rigid samplers: a stream's motion and next motion, and the composed motions of a roll-out.
_KEPT_MOTIONS = 16
_Key = tuple[float, float, float, int, int, float]  # (dx, dy, dyaw, height, width, res)
_kept: OrderedDict[_Key, Sampler] = OrderedDict()
_asked: OrderedDict[_Key, None] = OrderedDict()  # motions asked for once, sparse maps only
_lock = threading.Lock()  # Predictors in threads share the samplers


def _kept_sampler(key: _Key, sparse: bool = False) -> Sampler | None:
    """The sampler of a rigid motion, kept (the last :data:`_KEPT_MOTIONS`). For a ``sparse``
    map it is built on the motion's second use only (``None`` the first time: move it cell by
    cell), since a stream's carried objects meet new composed motions every scan and building
    a sampler costs many sparse moves."""
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
    """The NumPy :func:`lidarflow.ops.rigid.rigid_warp`: re-expresses ``height x width`` maps of
    the old sensor frame in the new one (``out(p)`` = the old map at :func:`transform_cells` of
    ``p``); kept process-wide by motion."""
    sampler = _kept_sampler(_key(motion, height, width, res))
    if sampler is None:  # only a sparse map's first ask goes without
        raise RuntimeError("a rigid sampler asked for a dense use was not built")
    return sampler


# The 5 x 5 window around a cell.
_WINDOW_ROWS, _WINDOW_COLS = (a.ravel() for a in np.mgrid[-2:3, -2:3])

# Below this share of occupied cells a map is moved cell by cell around its occupied ones.
_SPARSE_SHARE = 0.02


def _sparse_moved(image: np.ndarray, key: _Key) -> np.ndarray:
    """:func:`rigid_moved` of a map ``(H, W)`` with few nonzero cells, computed only where it
    can be nonzero: within sqrt(2) of where a nonzero cell lies in the new frame (the 5 x 5
    window around it), by the sampler's own elementwise arithmetic, so to the bit."""
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
    """``image`` ``(..., H, W)`` of the old sensor frame re-expressed in the new one
    (:func:`rigid_sampler`'s numbers), zero beyond the old grid; float64.

    >>> image = np.zeros((5, 4))
    >>> image[1, 1] = 1.0
    >>> np.argwhere(rigid_moved(image, np.array([1.0, 0.0, 0.0]))).tolist()  # 1 row closer
    [[2, 1]]
    """
    image = _exact(np.asarray(image))
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
