"""NumPy twins of :func:`lidarflow.ops.warp.warp` and :func:`lidarflow.ops.rigid.rigid_warp`:
a map moved by a flow, or re-expressed after the platform's own motion, for the parts of the
pipeline that run without PyTorch (the core install: the ONNX Predictor, ``evaluate``'s
baselines). Same conventions, same numbers (tests/motion/test_warp.py holds them to the torch
ops): bilinear sampling with cell centres at integers, zero outside the map."""

from __future__ import annotations

import numpy as np

__all__ = ["rigid_moved", "warp_map"]


def warp_map(image: np.ndarray, flow: np.ndarray) -> np.ndarray:
    """``out(p) = image(p + flow(p))`` ``(H, W)`` float64, bilinear, zero where ``p + flow(p)``
    falls outside the map; ``flow`` ``(2, H, W)`` in cells (column, row)."""
    image = np.asarray(image, np.float64)
    h, w = image.shape
    rows, cols = np.mgrid[0:h, 0:w].astype(np.float64)
    x = cols + np.asarray(flow[0], np.float64)
    y = rows + np.asarray(flow[1], np.float64)
    x0, y0 = np.floor(x), np.floor(y)
    out = np.zeros_like(image)
    for dy in (0, 1):
        for dx in (0, 1):
            xi, yi = x0 + dx, y0 + dy
            weight = (1.0 - np.abs(x - xi)) * (1.0 - np.abs(y - yi))
            inside = (xi >= 0) & (xi <= w - 1) & (yi >= 0) & (yi <= h - 1)
            xi = np.clip(xi, 0, w - 1).astype(np.intp)
            yi = np.clip(yi, 0, h - 1).astype(np.intp)
            out += np.where(inside, weight * image[yi, xi], 0.0)
    return out


def rigid_moved(image: np.ndarray, motion: np.ndarray, res: float = 1.0) -> np.ndarray:
    """``image`` ``(H, W)``, made in the old sensor frame, re-expressed in the new frame after
    the sensor moved by ``motion`` ``(dx, dy, dyaw)`` (the new frame's pose in the old one; ``dx,
    dy`` in the unit of ``res``: cells with ``res = 1``); zero where the new frame sees beyond
    the old grid (:mod:`lidarflow.ops.rigid`'s conventions)."""
    h, w = np.shape(image)
    dx, dy, yaw = (float(v) for v in np.asarray(motion, np.float64).reshape(3))
    rows, cols = np.mgrid[0:h, 0:w].astype(np.float64)
    x = (h - 0.5 - rows) * res
    y = (w / 2 - 0.5 - cols) * res
    cos, sin = np.cos(yaw), np.sin(yaw)
    x2, y2 = cos * x - sin * y + dx, sin * x + cos * y + dy  # new frame -> old
    flow = np.stack([w / 2 - 0.5 - y2 / res - cols, h - 0.5 - x2 / res - rows])
    return warp_map(image, flow)
