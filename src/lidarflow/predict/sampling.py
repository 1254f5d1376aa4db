"""Bilinear sampling in NumPy with its gathers and weights kept, for the per-frame warps of the
streaming step (issue 46).

:func:`lidarflow.ops.warp.warp` and :func:`lidarflow.ops.rigid.rigid_warp` build the sampling
grid on every call; in a stream the same grid serves many maps: the recurrent state and the
next map are moved by one motion, and every step of a roll-out assumes the same motion again.
A :class:`BilinearSampler` holds, for every cell, the four cells it reads and their weights
(zero for a cell outside the map), so moving ``C`` maps by it is four gathers;
:class:`RigidSamplers` keeps the last few by motion. Conventions are the torch ops' (cell
centres at integers, zero outside the map, :mod:`lidarflow.ops.rigid`'s motions);
tests/predict/test_sampling.py holds them to those ops.
"""

from __future__ import annotations

from collections import OrderedDict

import numpy as np

__all__ = ["BilinearSampler", "FlowWarp", "RigidSamplers", "rigid_positions"]


class BilinearSampler:
    """Samples ``(C, H, W)`` maps at fixed positions ``(cols, rows)`` ``(H, W)`` (in cells),
    bilinear, zero where a position's neighbour lies outside the map.

    >>> s = BilinearSampler(np.full((2, 3), 0.5), np.zeros((2, 3)))  # half a cell right of col 0
    >>> s(np.arange(6.0).reshape(1, 2, 3))[0, 0].tolist()
    [0.5, 0.5, 0.5]
    """

    def __init__(self, cols: np.ndarray, rows: np.ndarray) -> None:
        cols, rows = np.asarray(cols, np.float64), np.asarray(rows, np.float64)
        if cols.shape != rows.shape or cols.ndim != 2:
            raise ValueError(f"cols and rows must be one (H, W), got {cols.shape}, {rows.shape}")
        h, w = self.shape = cols.shape
        c0, r0 = np.floor(cols), np.floor(rows)
        fc, fr = cols - c0, rows - r0
        index, weight = [], []
        for dr, wr in ((0, 1.0 - fr), (1, fr)):
            for dc, wc in ((0, 1.0 - fc), (1, fc)):
                c, r = c0 + dc, r0 + dr
                inside = (c >= 0) & (c <= w - 1) & (r >= 0) & (r <= h - 1)
                flat = np.clip(r, 0, h - 1).astype(np.intp) * w + np.clip(c, 0, w - 1)
                index.append(flat.astype(np.intp).ravel())
                weight.append(np.where(inside, wr * wc, 0.0).ravel())
        self._index = np.stack(index)
        # float32 as the maps are (grid_sample's arithmetic); float64 maps are sampled in float64.
        self._weight = np.stack(weight)
        self._weight32 = self._weight.astype(np.float32)

    @classmethod
    def from_flow(cls, flow: np.ndarray) -> BilinearSampler:
        """The sampler of :func:`lidarflow.ops.warp.warp`'s ``flow`` ``(2, H, W)`` (cells,
        column then row): each cell reads at itself plus its flow."""
        flow = np.asarray(flow, np.float64)
        rows, cols = np.indices(flow.shape[1:], dtype=np.float64)
        return cls(cols + flow[0], rows + flow[1])

    def __call__(self, maps: np.ndarray) -> np.ndarray:
        """``maps`` ``(C, H, W)`` sampled, in their own float precision."""
        maps = np.asarray(maps)
        if maps.shape[-2:] != self.shape:
            h, w = self.shape
            raise ValueError(f"maps must be (C, {h}, {w}), got {maps.shape}")
        weight = self._weight32 if maps.dtype == np.float32 else self._weight
        flat = maps.reshape(maps.shape[0], -1)
        # np.take, in place: twice as fast as fancy indexing along the second axis.
        out = np.take(flat, self._index[0], axis=1)
        out *= weight[0]
        for k in range(1, 4):
            corner = np.take(flat, self._index[k], axis=1)
            corner *= weight[k]
            out += corner
        return out.reshape(maps.shape)


def rigid_positions(
    motion: np.ndarray, height: int, width: int, inverse: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """``(cols, rows)`` ``(H, W)``: where each cell of the new frame lies in the old one after
    the sensor moved by ``motion`` ``(dx, dy, dyaw)`` (cells, radians); ``inverse``: where each
    cell of the old frame lies in the new one (:func:`lidarflow.ops.rigid.transform_cells`)."""
    dx, dy, yaw = (float(v) for v in np.asarray(motion, np.float64).reshape(3))
    rows, cols = np.indices((height, width), dtype=np.float64)
    x, y = height - 0.5 - rows, width / 2 - 0.5 - cols
    cos, sin = np.cos(yaw), np.sin(yaw)
    if inverse:  # old -> new: R^T (p - d)
        x, y = x - dx, y - dy
        x2, y2 = cos * x + sin * y, -sin * x + cos * y
    else:  # new -> old: R p + d
        x2, y2 = cos * x - sin * y + dx, sin * x + cos * y + dy
    return width / 2 - 0.5 - y2, height - 0.5 - x2


class RigidSamplers:
    """The samplers of :func:`lidarflow.ops.rigid.rigid_warp` by a motion (cells, radians), the
    last ``size`` kept: a stream moves its state and its next map by one motion, and a roll-out
    assumes the same motion at every step. One per stream (not shared between threads)."""

    def __init__(self, size: int = 4) -> None:
        self.size = size
        self._kept: OrderedDict[tuple[float, ...], BilinearSampler] = OrderedDict()

    def __call__(self, motion: np.ndarray, height: int, width: int) -> BilinearSampler:
        m = np.asarray(motion, np.float64).reshape(3)
        key = (float(m[0]), float(m[1]), float(m[2]), float(height), float(width))
        sampler = self._kept.get(key)
        if sampler is None:
            sampler = BilinearSampler(*rigid_positions(m, height, width))
            if len(self._kept) >= self.size:
                self._kept.popitem(last=False)
            self._kept[key] = sampler
        else:
            self._kept.move_to_end(key)
        return sampler


class FlowWarp:
    """:func:`lidarflow.motion.warp.warp_map` (float64) with the sampler of the last flow kept:
    a roll-out moves every fed-back map by the same flow where the model's flow is the
    platform's motion alone (comparing the flow costs a tenth of building the sampler)."""

    def __init__(self) -> None:
        self._flow: np.ndarray | None = None
        self._sampler: BilinearSampler | None = None

    def __call__(self, image: np.ndarray, flow: np.ndarray) -> np.ndarray:
        """``image`` ``(H, W)`` sampled at each cell plus ``flow`` ``(2, H, W)``, float64."""
        if self._sampler is None or self._flow is None or not np.array_equal(flow, self._flow):
            self._flow = np.array(flow, copy=True)
            self._sampler = BilinearSampler.from_flow(self._flow)
        return self._sampler(np.asarray(image, np.float64)[None])[0]
