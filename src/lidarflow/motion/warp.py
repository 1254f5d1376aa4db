"""NumPy twins of :func:`lidarflow.ops.warp.warp` and :func:`lidarflow.ops.rigid.rigid_warp`:
a map moved by a flow, or re-expressed after the platform's own motion, for the parts of the
pipeline that run without PyTorch (the core install: the ONNX Predictor, ``evaluate``'s
baselines). Same conventions, same numbers (tests/motion/test_warp.py holds them to the torch
ops): bilinear sampling with cell centres at integers, zero outside the map.

A warp is split in two: the four corners each cell reads and their weights (``_corners``, most
of the cost), then the gathers. A rigid motion's corners are kept (a small cache by motion):
a tracker moves its background and its seen map by the same motion, and the carried objects
one frame on by that motion again (issue 46). The arithmetic is the one the single-pass warp
did, in the same order, so the numbers are the same to the bit.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

__all__ = ["rigid_moved", "warp_map"]

# Kept rigid motions' corners (640 KB each on a 100 x 100 map): a stream's motion and the
# composed motions of a roll-out of 8 steps.
_KEPT_MOTIONS = 12


def _corners(flow: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(index (4, H*W), weight (4, H*W))``: for each cell of ``flow`` ``(2, H, W)`` the flat
    index of the four cells it reads (clipped into the map) and their bilinear weights, zero
    where a corner lies outside the map."""
    h, w = flow.shape[1:]
    rows, cols = np.mgrid[0:h, 0:w].astype(np.float64)
    x = cols + np.asarray(flow[0], np.float64)
    y = rows + np.asarray(flow[1], np.float64)
    x0, y0 = np.floor(x), np.floor(y)
    index, weight = [], []
    for dy in (0, 1):
        for dx in (0, 1):
            xi, yi = x0 + dx, y0 + dy
            wi = (1.0 - np.abs(x - xi)) * (1.0 - np.abs(y - yi))
            inside = (xi >= 0) & (xi <= w - 1) & (yi >= 0) & (yi <= h - 1)
            xi = np.clip(xi, 0, w - 1).astype(np.intp)
            yi = np.clip(yi, 0, h - 1).astype(np.intp)
            index.append((yi * w + xi).ravel())
            weight.append(np.where(inside, wi, 0.0).ravel())
    return np.stack(index), np.stack(weight)


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


@lru_cache(maxsize=_KEPT_MOTIONS)
def _rigid_corners(
    dx: float, dy: float, yaw: float, h: int, w: int, res: float
) -> tuple[np.ndarray, np.ndarray]:
    rows, cols = np.mgrid[0:h, 0:w].astype(np.float64)
    x = (h - 0.5 - rows) * res
    y = (w / 2 - 0.5 - cols) * res
    cos, sin = np.cos(yaw), np.sin(yaw)
    x2, y2 = cos * x - sin * y + dx, sin * x + cos * y + dy  # new frame -> old
    flow = np.stack([w / 2 - 0.5 - y2 / res - cols, h - 0.5 - x2 / res - rows])
    index, weight = _corners(flow)
    index.setflags(write=False)  # shared by every caller of the cache
    weight.setflags(write=False)
    return index, weight


def rigid_moved(image: np.ndarray, motion: np.ndarray, res: float = 1.0) -> np.ndarray:
    """``image`` ``(H, W)`` (or a stack ``(C, H, W)``, each moved alike), made in the old sensor
    frame, re-expressed in the new frame after the sensor moved by ``motion`` ``(dx, dy,
    dyaw)`` (the new frame's pose in the old one; ``dx, dy`` in the unit of ``res``: cells with
    ``res = 1``); zero where the new frame sees beyond the old grid (:mod:`lidarflow.ops.
    rigid`'s conventions). float64."""
    image = np.asarray(image, np.float64)
    h, w = image.shape[-2:]
    if not image.any():  # nothing to move (often so for the carried objects)
        return np.zeros(image.shape)
    dx, dy, yaw = (float(v) for v in np.asarray(motion, np.float64).reshape(3))
    corners = _rigid_corners(dx, dy, yaw, h, w, float(res))
    return _sampled(image.reshape(-1, h * w), corners, image.shape)
