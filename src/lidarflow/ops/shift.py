"""The constant-velocity extrapolation of a map in torch (batched, ONNX-exportable): the same
answer as :class:`lidarflow.baselines.ConstantVelocity`, tie rule included (most overlapping
occupied cells, then the smallest ``|d_col| + |d_row|``, then the first in row-major order).

Both steps are grouped convolutions over the batch (so an exported graph is fixed to its export
batch): the maps' correlation at every shift, then separable one-hot kernels at the chosen
shift. The data-dependent kernels stay float32 (bf16 autocast is switched off here: it would
round overlap counts above 256).
"""

from __future__ import annotations

from typing import NamedTuple

import torch
import torch.nn.functional as F
from torch import Tensor

__all__ = [
    "DEFAULT_RADIUS",
    "ShiftKernels",
    "apply_shift",
    "best_shift_kernel",
    "shift_scores",
]

#: The baseline's search radius in cells per frame (0.3 m at 0.1 m cells).
DEFAULT_RADIUS = 3


# Not 0.5 itself: a map moved by exactly half a cell holds cells of 0.5, which PyTorch's and
# ONNX's warps leave 1e-5 either side, so the two backends would choose different shifts.
_OCCUPIED_ABOVE = 0.5 - 1e-3


def shift_scores(previous: Tensor, current: Tensor, radius: int = DEFAULT_RADIUS) -> Tensor:
    """``(B, (2 radius + 1)^2)`` scores, row-major over ``(d_row, d_col)`` in
    ``[-radius, radius]^2``, whose first maximum is the baseline's shift: the overlap of
    ``previous`` moved by the shift with ``current``, then the shift's size."""
    b, _, h, w = current.shape
    prev = (previous > _OCCUPIED_ABOVE).float()
    cur = F.pad((current > _OCCUPIED_ABOVE).float(), (radius, radius, radius, radius))
    # out(i, j) = sum_q prev(q) cur(q + (i - radius, j - radius)): the overlap at that shift.
    overlap = F.conv2d(cur.reshape(1, b, h + 2 * radius, w + 2 * radius), prev, groups=b)
    overlap = overlap.reshape(b, -1)
    steps = torch.arange(-radius, radius + 1, device=current.device, dtype=overlap.dtype)
    size = (steps.view(-1, 1).abs() + steps.view(1, -1).abs()).reshape(1, -1)
    # Counts are integers and a shift's size is at most 2 radius < the factor, so ordering by
    # this score is ordering by (overlap, -size); float32 is exact below 2^24 / factor cells.
    return overlap * (4.0 * radius + 1.0) - size


class ShiftKernels(NamedTuple):
    """One map's shift as two one-hot kernels, ``rows`` ``(B, 1, k, 1)`` and ``cols``
    ``(B, 1, 1, k)``, whose outer product is the shift's ``k x k`` kernel."""

    rows: Tensor
    cols: Tensor


def best_shift_kernel(
    previous: Tensor, current: Tensor, radius: int = DEFAULT_RADIUS
) -> ShiftKernels:
    """For each map, the baseline's best shift from ``previous`` to ``current``
    ``(B, 1, H, W)``, for :func:`apply_shift`; a zero ``previous`` gives shift 0."""
    if current.dim() != 4 or current.shape[1] != 1:
        raise ValueError(f"maps must be (B, 1, H, W), got {tuple(current.shape)}")
    if previous.shape != current.shape:
        raise ValueError(
            f"previous and current must match, got {tuple(previous.shape)}, {tuple(current.shape)}"
        )
    b = current.shape[0]
    side = 2 * radius + 1
    with torch.autocast(current.device.type, enabled=False):
        scores = shift_scores(previous, current, radius)
        choice = torch.argmax(scores, dim=1, keepdim=True)  # (d_row + r) * side + d_col + r
        taps = torch.arange(side, device=current.device).view(1, -1)
        # A kernel tap at i reads cur(r + i - radius): the shift d is the tap radius - d,
        # hence the reversed index.
        rows = (taps == side - 1 - torch.div(choice, side, rounding_mode="floor")).float()
        cols = (taps == side - 1 - torch.remainder(choice, side)).float()
        return ShiftKernels(rows.view(b, 1, side, 1), cols.view(b, 1, 1, side))


def apply_shift(maps: Tensor, kernels: ShiftKernels) -> Tensor:
    """``maps`` ``(B, C, H, W)``, every channel of map ``b`` moved by map ``b``'s shift (from
    :func:`best_shift_kernel`); cells moved in from outside are 0."""
    b, c, h, w = maps.shape
    side = kernels.rows.shape[2]
    radius = side // 2
    if kernels.rows.shape != (b, 1, side, 1) or kernels.cols.shape != (b, 1, 1, side):
        raise ValueError(
            f"kernels must be ({b}, 1, k, 1) and ({b}, 1, 1, k), got "
            f"{tuple(kernels.rows.shape)} and {tuple(kernels.cols.shape)}"
        )
    with torch.autocast(maps.device.type, enabled=False):
        padded = F.pad(maps.float(), (radius, radius, radius, radius))
        # Channel-major groups: group b * c + i is channel i of map b, read by map b's kernels.
        rows, cols = (k.repeat_interleave(c, dim=0) if c > 1 else k for k in kernels)
        moved = F.conv2d(
            padded.reshape(1, b * c, h + 2 * radius, w + 2 * radius), rows, groups=b * c
        )
        moved = F.conv2d(moved, cols, groups=b * c)
    return moved.reshape(b, c, h, w).to(maps.dtype)
