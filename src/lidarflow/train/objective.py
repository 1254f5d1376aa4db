"""The loss a run minimises, per model type, and the Gaussian size the warp loss follows.

``flownet``: ``loss.warp`` x :func:`lidarflow.losses.flow_loss` with the epoch's Gaussian size,
plus ``loss.occupancy_bce`` x the occupancy head's cross-entropy; ``deeptracking``:
:func:`~lidarflow.losses.deeptracking_loss`; ``sogmp``: :func:`~lidarflow.losses.sogmp_loss`.
All count only pairs after ``data.warmup`` frames.
"""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch import Tensor

from lidarflow.errors import TrainError
from lidarflow.losses import (
    deeptracking_loss,
    flow_loss,
    gaussian_schedule,
    next_map_bce,
    sogmp_loss,
)
from lidarflow.train.config import TrainConfig

__all__ = ["gaussian_size", "make_loss"]


def gaussian_size(config: TrainConfig, epoch: int) -> int:
    """Filter size of 0-based ``epoch``: the paper's 9 -> 1 schedule, 1 for ``--no-gaussian``."""
    s = config.schedule
    if not s.gaussian:
        return 1
    return gaussian_schedule(epoch, s.gaussian_start, s.gaussian_step_epochs, s.gaussian_min)


def make_loss(
    config: TrainConfig, kernel: int, model: torch.nn.Module | None = None
) -> Callable[[Tensor, Tensor], Tensor]:
    """``loss(seq (B,T,2,H,W), out (B,T,C,H,W)) -> scalar`` for the configured model (the
    unwrapped ``model`` is needed for the occupancy head's cross-entropy)."""
    warmup = config.data.warmup
    if config.model.name == "deeptracking":
        return lambda seq, out: deeptracking_loss(seq, out, warmup=warmup)
    if config.model.name == "sogmp":
        return lambda seq, out: sogmp_loss(seq, out, warmup, config.loss.kl_weight)
    weight = config.loss.occupancy_bce
    head = model is not None and model.capabilities.occupancy_head
    if weight > 0.0 and not head:
        raise TrainError(
            "loss.occupancy_bce needs a model with an occupancy head: add "
            "--set model.head.hidden_channels=0 (or use --recipe head)"
        )

    def loss(seq: Tensor, out: Tensor) -> Tensor:
        value = seq.new_zeros(())  # loss.warp = 0: the exact flow alone teaches (supervised)
        if config.loss.warp > 0.0:
            flows = out[:, :, :4]
            value = config.loss.warp * flow_loss(seq, flows, kernel, config.loss, warmup=warmup)
        if weight > 0.0:
            b, t, c, h, w = out.shape
            logits = model.next_logit(seq.reshape(b * t, -1, h, w), out.reshape(b * t, c, h, w))
            value = value + weight * next_map_bce(
                seq,
                logits.reshape(b, t, 1, h, w),
                warmup=warmup,
                visible_only=config.loss.occupancy_visible_only,
                changed_weight=config.loss.occupancy_changed_weight,
            )
        return value

    return loss
