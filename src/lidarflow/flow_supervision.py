"""Supervised flow loss: end-point error against the simulator's exact flow
(``docs/research/flow_supervised/``).

The exact ``B^t`` is defined on the cells occupied in ``O^{t+1}``, ``F^t`` on those occupied in
``O^t`` (:mod:`lidarflow.sim.groundtruth`); other cells are not counted. A cell is *moving* when
its exact flow differs from the platform's (:func:`platform_flows`) by more than ``threshold``
cells; it weighs ``moving_weight`` times a static one, so that the static majority does not
make "everything moves with the platform" the cheapest fit. The per-cell error is the
Charbonnier form ``sqrt(|e|^2 + eps^2) - eps``: 0 for the exact flow, differentiable at zero.
"""

from __future__ import annotations

import torch
from torch import Tensor

from lidarflow.ops.rigid import cell_grid, rigid_flow, transform_cells

__all__ = [
    "EPS",
    "MOVING_FLOW_THRESHOLD",
    "flow_epe_loss",
    "moving_cells",
    "platform_flows",
    "window_flow_loss",
]

#: Cells per frame by which a cell's exact flow must differ from the platform's to count as
#: moving: above a rigid motion's spread across one cell (~0.05), below a walker's (0.2-1.2).
MOVING_FLOW_THRESHOLD = 0.15

#: Charbonnier epsilon (cells): the loss is quadratic below it, linear above.
EPS = 1e-3


def platform_flows(motion: Tensor, height: int, width: int) -> Tensor:
    """The flow of a static world seen from a moving platform, ``(N, 4, H, W)`` in cells
    (``B_col, B_row, F_col, F_row``), for ``motion`` ``(N, 3)``: the pose of frame ``t + 1`` in
    frame ``t`` (``dx, dy`` in cells; :mod:`lidarflow.ops.rigid`). ``B(q) = T(q) - q`` takes a
    cell of frame ``t + 1`` to where its point was in frame ``t``; ``F(p) = T^{-1}(p) - p``."""
    backward = rigid_flow(motion, height, width)
    c, r = cell_grid(height, width, motion.device, backward.dtype)
    c2, r2 = transform_cells(c, r, motion.to(backward.dtype), height, width, inverse=True)
    return torch.cat([backward, torch.stack([c2 - c, r2 - r], dim=1)], dim=1)


def moving_cells(truth: Tensor, platform: Tensor | None, threshold: float) -> Tensor:
    """Bool ``(N, D, H, W)`` -> ``(N, D // 2, H, W)``: per direction, the cells whose exact flow
    ``truth`` differs from ``platform`` (``None``: zero) by more than ``threshold`` cells."""
    residual = truth if platform is None else truth - platform
    n, d, h, w = residual.shape
    return residual.reshape(n, d // 2, 2, h, w).norm(dim=2) > threshold


def flow_epe_loss(
    flow: Tensor,
    truth: Tensor,
    defined: Tensor,
    moving: Tensor,
    moving_weight: float = 10.0,
    eps: float = EPS,
) -> Tensor:
    """Weighted mean Charbonnier end-point error over the cells where the truth is defined.

    Args:
        flow: ``(N, 2 D, H, W)`` estimated flow, ``D`` directions of (column, row) cells.
        truth: ``(N, 2 D, H, W)`` exact flow.
        defined: bool ``(N, D, H, W)``: where each direction's truth is defined.
        moving: bool ``(N, D, H, W)``: the moving cells (:func:`moving_cells`).
        moving_weight: weight of a defined moving cell relative to a defined static one (>= 0).
        eps: Charbonnier epsilon (cells).

    Returns:
        A scalar: ``sum(w e) / sum(w)`` with ``w = defined * (1 + (moving_weight - 1) moving)``;
        0 where nothing is defined.
    """
    if flow.shape != truth.shape or flow.dim() != 4 or flow.shape[1] % 2:
        raise ValueError(
            f"flow and truth must both be (N, 2D, H, W), got {tuple(flow.shape)} and "
            f"{tuple(truth.shape)}"
        )
    n, c, h, w = flow.shape
    want = (n, c // 2, h, w)
    if tuple(defined.shape) != want or tuple(moving.shape) != want:
        raise ValueError(
            f"defined and moving must be {want}, got {tuple(defined.shape)} and "
            f"{tuple(moving.shape)}"
        )
    if not moving_weight >= 0.0:
        raise ValueError(f"moving_weight must be >= 0, got {moving_weight}")
    diff = (flow - truth).reshape(n, c // 2, 2, h, w)
    err = (diff.square().sum(dim=2) + eps * eps).sqrt() - eps
    weight = defined.to(err.dtype) * (1.0 + (moving_weight - 1.0) * moving.to(err.dtype))
    return (err * weight).sum() / weight.sum().clamp_min(1.0)


def window_flow_loss(
    seq: Tensor,
    out: Tensor,
    truth: Tensor,
    motions: Tensor | None,
    warmup: int,
    moving_weight: float,
    threshold: float,
) -> Tensor:
    """:func:`flow_epe_loss` of a batch of training windows over pairs ``t = warmup .. T-2``.

    Args:
        seq: ``(B, T, C, H, W)`` maps, channel 0 occupancy.
        out: ``(B, T, >= 4, H, W)`` model outputs; ``out[:, t, :4]`` is ``B^t, F^t``.
        truth: ``(B, T, 2 or 4, H, W)``: ``B^t`` (and ``F^t``) at index ``t``, as the
            simulator stores them; with 2 channels only the backward flow is taught.
        motions: ``(B, T, 3)`` per-frame motion (frame ``t`` in frame ``t - 1``, cells), for
            the platform's flow of pair ``t`` (``motions[:, t + 1]``); ``None``: a platform
            that stands still.
    """
    _, t, _, h, w = seq.shape
    pairs = slice(warmup, t - 1)
    d = truth.shape[2]
    if d not in (2, 4):
        raise ValueError(f"truth must have 2 (B) or 4 (B, F) channels, got {d}")
    est = out[:, pairs, :d].reshape(-1, d, h, w)
    gt = truth[:, pairs].reshape(-1, d, h, w).to(est.dtype)
    occ_now = seq[:, pairs, 0] > 0.5
    occ_next = seq[:, warmup + 1 :, 0] > 0.5
    defined = (occ_next if d == 2 else torch.stack([occ_next, occ_now], dim=2)).reshape(
        -1, d // 2, h, w
    )
    platform = None
    if motions is not None:
        platform = platform_flows(motions[:, warmup + 1 :].reshape(-1, 3).to(est.dtype), h, w)
        platform = platform[:, :d]
    return flow_epe_loss(est, gt, defined, moving_cells(gt, platform, threshold), moving_weight)
