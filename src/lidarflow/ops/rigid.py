"""Differentiable rigid (planar) warp of sensor-frame grids by the sensor's own motion.

The grid and motion conventions are :mod:`lidarflow.geometry`'s (its NumPy twin): ``motion =
(dx, dy, dyaw)`` is the pose of the *new* sensor frame in the *old* one. ``rigid_warp(old_map,
motion)`` re-expresses a map made in the old frame in the new one: ``out(p) = old(T(p))``,
bilinear, ``fill`` beyond the old grid. It is :func:`lidarflow.ops.warp.warp` with the flow
``T(p) - p`` (:func:`rigid_flow`), differentiable in the maps and the motion.
"""

from __future__ import annotations

import torch
from torch import Tensor

from lidarflow.ops.warp import warp, warp_gather

__all__ = ["cell_grid", "rigid_flow", "rigid_warp", "transform_cells"]


def _check_motion(motion: Tensor, batch: int | None = None) -> None:
    if motion.dim() != 2 or motion.shape[1] != 3:
        raise ValueError(f"motion must be (B, 3) (dx, dy, dyaw), got {tuple(motion.shape)}")
    if batch is not None and motion.shape[0] != batch:
        raise ValueError(f"motion has {motion.shape[0]} rows for a batch of {batch}")


def cell_grid(
    height: int,
    width: int,
    device: torch.device | str | None = None,
    dtype: torch.dtype = torch.float32,
) -> tuple[Tensor, Tensor]:
    """Column and row index of every cell, each ``(H, W)``."""
    rows = torch.arange(height, device=device, dtype=dtype)
    cols = torch.arange(width, device=device, dtype=dtype)
    r, c = torch.meshgrid(rows, cols, indexing="ij")
    return c, r


def transform_cells(
    cols: Tensor,
    rows: Tensor,
    motion: Tensor,
    height: int,
    width: int,
    res: float = 1.0,
    inverse: bool = False,
) -> tuple[Tensor, Tensor]:
    """Continuous cell coordinates ``cols, rows`` (broadcastable to ``(B, H', W')``) of a
    ``height x width`` grid moved from the new frame to the old one (``inverse``: old to new)
    by ``motion`` ``(B, 3)`` (``dx, dy`` in the unit of ``res``); ``(cols, rows)``
    ``(B, H', W')``."""
    _check_motion(motion)
    dx, dy, yaw = (motion[:, i].reshape(-1, 1, 1) for i in range(3))
    x = (height - 0.5 - rows) * res
    y = (width / 2 - 0.5 - cols) * res
    cos, sin = torch.cos(yaw), torch.sin(yaw)
    if inverse:  # old -> new: R^T (p - d)
        x, y = x - dx, y - dy
        x2, y2 = cos * x + sin * y, -sin * x + cos * y
    else:  # new -> old: R p + d
        x2, y2 = cos * x - sin * y + dx, sin * x + cos * y + dy
    return width / 2 - 0.5 - y2 / res, height - 0.5 - x2 / res


def rigid_flow(
    motion: Tensor,
    height: int,
    width: int,
    res: float = 1.0,
    dtype: torch.dtype | None = None,
) -> Tensor:
    """The flow ``(B, 2, H, W)`` in cells (column, row) from each cell of the new frame to where
    the same point lies in the old frame's grid; ``warp(old, rigid_flow(m)) == rigid_warp(old, m)``.

    >>> f = rigid_flow(torch.tensor([[2.0, 0.0, 0.0]]), 4, 4)  # 2 cells forward
    >>> f[0, :, 0, 0].tolist()  # far row samples 2 rows further away (row index - 2)
    [0.0, -2.0]
    """
    _check_motion(motion)
    dtype = dtype or (motion.dtype if motion.is_floating_point() else torch.float32)
    motion = motion.to(dtype)
    c, r = cell_grid(height, width, motion.device, dtype)
    c2, r2 = transform_cells(c, r, motion, height, width, res)
    return torch.stack([c2 - c, r2 - r], dim=1)


def rigid_warp(
    maps: Tensor, motion: Tensor, res: float = 1.0, fill: float = 0.0, gather: bool = False
) -> Tensor:
    """``maps`` ``(B, C, H, W)`` of the old sensor frame re-expressed in the new one after the
    motion ``(B, 3)``; ``fill`` beyond the old grid. ``gather``: sample with
    :func:`~lidarflow.ops.warp.warp_gather` (the same values; faster for many channels in
    onnxruntime, slower in PyTorch).

    >>> m = torch.zeros(1, 1, 5, 4)
    >>> m[0, 0, 1, 1] = 1.0
    >>> round(rigid_warp(m, torch.tensor([[1.0, 0.0, 0.0]]))[0, 0, 2, 1].item(), 4)  # 1 row closer
    1.0
    """
    if maps.dim() != 4:
        raise ValueError(f"maps must be (B, C, H, W), got {tuple(maps.shape)}")
    _check_motion(motion, maps.shape[0])
    h, w = int(maps.shape[-2]), int(maps.shape[-1])
    flow = rigid_flow(motion, h, w, res, dtype=maps.dtype)
    sample = warp_gather if gather else warp
    if fill == 0.0:
        return sample(maps, flow)
    return sample(maps - fill, flow) + fill
