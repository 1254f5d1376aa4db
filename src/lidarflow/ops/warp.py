"""Differentiable bilinear warp of maps by a flow field in cells (design notes section 3).

``W(I, f)(p)`` is the bilinear sample of ``I`` at ``p + f(p)``, zero outside the map, as in a
spatial transformer network. Flow is measured in cells; channel 0 is the column (image-x)
displacement and channel 1 the row (image-y) displacement. With the backward flow ``B^t`` of
LiDAR-FlowNet, ``O^{t+1}(p) = O^t(p + B^t(p))``, i.e. ``O^{t+1} = warp(O^t, B^t)``.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

# Base grids keyed by (H, W, device, dtype): never written to and without grad, so one per grid
# size serves every call (a training step warps the same size thousands of times).
_BASE_GRIDS: dict[tuple[int, int, str, torch.dtype], tuple[Tensor, Tensor]] = {}
_MAX_CACHED = 16


def _base_grid(
    height: int, width: int, device: torch.device, dtype: torch.dtype
) -> tuple[Tensor, Tensor]:
    """The identity sampling grid ``(1, H, W, 2)`` in normalised coordinates and the
    per-axis scale ``(2,)`` that turns a displacement in cells into normalised units."""
    # While a tracer runs (torch.export, torch.compile, the ONNX exporter) the tensors made here
    # belong to the trace: they must neither come from nor go into the cache.
    tracing = torch.jit.is_tracing() or torch.compiler.is_compiling()
    key = (height, width, str(device), dtype)
    cached = None if tracing else _BASE_GRIDS.get(key)
    if cached is not None:
        return cached
    # Made in NumPy so that a tracer records a constant (traced from torch.linspace, the ONNX
    # exporter types the grid as double, which onnxruntime's GridSample rejects), and outside
    # inference mode: a cached inference tensor would break every later call that autograd
    # tracks (training, tracing) in the same process.
    cols = np.linspace(-1.0, 1.0, width)
    rows = np.linspace(-1.0, 1.0, height)
    grid_np = np.stack(np.meshgrid(cols, rows, indexing="xy"), axis=-1)[None]
    scale_np = np.array([2.0 / (width - 1), 2.0 / (height - 1)])
    with torch.inference_mode(False):
        grid = torch.from_numpy(grid_np).to(device=device, dtype=dtype)
        scale = torch.from_numpy(scale_np).to(device=device, dtype=dtype)
    if not tracing:
        if len(_BASE_GRIDS) >= _MAX_CACHED:
            _BASE_GRIDS.clear()
        _BASE_GRIDS[key] = (grid, scale)
    return grid, scale


def warp(maps: Tensor, flow: Tensor) -> Tensor:
    """``maps`` ``(B, C, H, W)`` sampled bilinearly at ``p + flow(p)``, zero outside the map:
    ``out[b, :, r, c] = maps[b, :, r + flow[b, 1, r, c], c + flow[b, 0, r, c]]``, with ``flow``
    ``(B, 2, H, W)`` in cells (column, row). Differentiable in both; ``grid_sample`` with
    ``align_corners=True``, so cell centres sit on the sampling lattice; ``H, W >= 2``.

    Example:
        >>> maps = torch.zeros(1, 1, 3, 4)
        >>> maps[0, 0, 1, 2] = 1.0
        >>> flow = torch.zeros(1, 2, 3, 4)
        >>> flow[:, 0] = 1.0  # every cell samples from its right-hand neighbour
        >>> warp(maps, flow)[0, 0]
        tensor([[0., 0., 0., 0.],
                [0., 1., 0., 0.],
                [0., 0., 0., 0.]])
    """
    h, w = _check(maps, flow)
    if flow.dtype != maps.dtype:
        # Under autocast the flow may come out in a lower precision than the maps; sample in the
        # maps' precision so the occupancy is not rounded.
        flow = flow.to(maps.dtype)
    base, scale = _base_grid(h, w, maps.device, maps.dtype)
    # One fused op (and one allocation) for base + flow * scale, in grid_sample's (B, H, W, 2).
    grid = torch.addcmul(base, flow.permute(0, 2, 3, 1), scale)
    return F.grid_sample(maps, grid, mode="bilinear", padding_mode="zeros", align_corners=True)


def warp_gather(maps: Tensor, flow: Tensor) -> Tensor:
    """:func:`warp` computed as four gathers of whole cells (all channels at once): the same
    function, faster for many channels in onnxruntime, whose ``GridSample`` samples channel by
    channel."""
    h, w = _check(maps, flow)
    flow = flow.to(maps.dtype)
    b, c = maps.shape[0], maps.shape[1]
    cols, rows = _cell_indices(h, w, maps.device, maps.dtype)
    x, y = cols + flow[:, 0], rows + flow[:, 1]  # (B, H, W) where each cell samples
    x0, y0 = torch.floor(x), torch.floor(y)
    fx, fy = x - x0, y - y0
    table = maps.permute(0, 2, 3, 1).reshape(b * h * w, c)
    first = (torch.arange(b, device=maps.device) * (h * w)).view(b, 1, 1)
    out = None
    for dy, wy in ((0.0, 1.0 - fy), (1.0, fy)):
        for dx, wx in ((0.0, 1.0 - fx), (1.0, fx)):
            xi, yi = x0 + dx, y0 + dy
            inside = (xi >= 0) & (xi <= w - 1) & (yi >= 0) & (yi <= h - 1)
            weight = torch.where(inside, wx * wy, torch.zeros_like(wx))
            index = yi.clamp(0, h - 1).long() * w + xi.clamp(0, w - 1).long() + first
            term = table[index.reshape(-1)].view(b, h, w, c) * weight.unsqueeze(-1)
            out = term if out is None else out + term
    assert out is not None
    return out.permute(0, 3, 1, 2)


def _cell_indices(
    height: int, width: int, device: torch.device, dtype: torch.dtype
) -> tuple[Tensor, Tensor]:
    """Column and row index of every cell, ``(1, H, W)`` each (NumPy-made: a constant in a
    trace, see :func:`_base_grid`)."""
    rows, cols = np.meshgrid(np.arange(height), np.arange(width), indexing="ij")
    with torch.inference_mode(False):
        c = torch.from_numpy(cols[None].astype(np.float64)).to(device=device, dtype=dtype)
        r = torch.from_numpy(rows[None].astype(np.float64)).to(device=device, dtype=dtype)
    return c, r


def _check(maps: Tensor, flow: Tensor) -> tuple[int, int]:
    """Validate a warp's inputs; the grid size as ints (a constant of an exported graph, though
    a tracer may hand the sizes as tensors or symbols)."""
    if maps.dim() != 4:
        raise ValueError(f"maps must be (B, C, H, W), got {tuple(maps.shape)}")
    if flow.dim() != 4 or flow.shape[1] != 2:
        raise ValueError(f"flow must be (B, 2, H, W), got {tuple(flow.shape)}")
    b, _, h, w = maps.shape
    if flow.shape[0] != b or flow.shape[2:] != maps.shape[2:]:
        raise ValueError(
            f"flow {tuple(flow.shape)} does not match maps {tuple(maps.shape)}: "
            "expected the same batch size and grid"
        )
    if h < 2 or w < 2:
        raise ValueError(f"maps must be at least 2 x 2 cells to warp, got {tuple(maps.shape)}")
    if not (maps.is_floating_point() and flow.is_floating_point()):
        raise ValueError(f"maps and flow must be floating point, got {maps.dtype} and {flow.dtype}")
    return int(h), int(w)
