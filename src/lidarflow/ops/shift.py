"""The constant-velocity extrapolation of a map, in torch (batched, ONNX-exportable).

:class:`lidarflow.evaluate.baselines.ConstantVelocity` finds the integer shift that best maps
the previous occupancy map onto the current one and applies it once more. A model that sees
this extrapolation as an input starts from the baseline it is judged against on a moving
platform instead of having to rediscover it (issue 11: a flow network trained on simulation lost
to it on both moving recordings). Same answer as the NumPy baseline, including its tie rule
(most overlapping occupied cells, then the smallest ``|d_col| + |d_row|``, then the first in
row-major order), so the model's input and the baseline's prediction are the same map.

Every shift is a static slice of a zero-padded map and the choice is an ``argmax`` turned into
a one-hot weighting: no data-dependent Python branching, so a step graph that uses it exports
to ONNX for any batch size.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

__all__ = ["all_shifts", "best_shift", "constant_velocity_map"]


def _offsets(radius: int) -> list[tuple[int, int]]:
    # (d_col, d_row), rows outer and columns inner: the baseline's search order.
    return [(dc, dr) for dr in range(-radius, radius + 1) for dc in range(-radius, radius + 1)]


def all_shifts(image: Tensor, radius: int) -> Tensor:
    """``(B, 1, H, W)`` -> ``(B, S, H, W)``: the map moved by every ``(d_col, d_row)`` with
    ``|d| <= radius`` (zeros enter), ``S = (2 radius + 1)^2`` in the baseline's search order.
    Channel ``s`` holds ``out(r, c) = image(r - d_row, c - d_col)``."""
    if image.dim() != 4 or image.shape[1] != 1:
        raise ValueError(f"image must be (B, 1, H, W), got {tuple(image.shape)}")
    h, w = image.shape[-2:]
    padded = F.pad(image, (radius, radius, radius, radius))
    return torch.cat(
        [
            padded[:, :, radius - dr : radius - dr + h, radius - dc : radius - dc + w]
            for dc, dr in _offsets(radius)
        ],
        dim=1,
    )


def best_shift(previous: Tensor, current: Tensor, radius: int = 3) -> Tensor:
    """One-hot ``(B, S, 1, 1)`` over :func:`all_shifts`'s order: the shift of ``previous`` with
    the most occupied cells in common with ``current`` (ties: the smallest shift)."""
    overlap = (all_shifts((previous > 0.5).to(current.dtype), radius) * (current > 0.5)).sum(
        dim=(2, 3)
    )
    size = torch.tensor(
        [abs(dc) + abs(dr) for dc, dr in _offsets(radius)],
        dtype=overlap.dtype,
        device=overlap.device,
    )
    # Overlap counts are integers, a shift's size is at most 2 radius < the factor: ordering by
    # this score is ordering by (overlap, -size). float32 is exact up to 2^24 / factor cells.
    factor = 4.0 * radius + 1.0
    choice = torch.argmax(overlap * factor - size, dim=1, keepdim=True)
    index = torch.arange(overlap.shape[1], device=overlap.device).view(1, -1)
    return (index == choice).to(current.dtype)[..., None, None]


def constant_velocity_map(previous: Tensor, current: Tensor, radius: int = 3) -> Tensor:
    """``current`` ``(B, 1, H, W)`` moved once more by the best shift from ``previous`` to it:
    the constant-velocity baseline's prediction of the next map. A zero ``previous`` (the first
    frame) gives shift 0, i.e. ``current``."""
    if previous.shape != current.shape:
        raise ValueError(
            f"previous and current must match, got {tuple(previous.shape)}, {tuple(current.shape)}"
        )
    return (all_shifts(current, radius) * best_shift(previous, current, radius)).sum(
        dim=1, keepdim=True
    )
