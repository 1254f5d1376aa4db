"""The loss a run minimises, per model type (the module docstring of
:mod:`lidarflow.train.loop` lists them), and the Gaussian filter's schedule the warp loss
follows."""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

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

__all__ = ["Loss", "gaussian_size", "make_loss"]


class Loss(Protocol):
    """``loss(seq (B,T,C,H,W), out (B,T,C',H,W), region (B,T,H,W) or None) -> scalar``."""

    def __call__(self, seq: Tensor, out: Tensor, region: Tensor | None = None) -> Tensor: ...


def gaussian_size(config: TrainConfig, epoch: int) -> int:
    """Filter size of 0-based ``epoch``: the paper's 9 -> 1 schedule, 1 for ``--no-gaussian``."""
    s = config.schedule
    if not s.gaussian:
        return 1
    return gaussian_schedule(epoch, s.gaussian_start, s.gaussian_step_epochs, s.gaussian_min)


def make_loss(config: TrainConfig, kernel: int, model: torch.nn.Module | None = None) -> Loss:
    """``loss(seq (B,T,2,H,W), out (B,T,C,H,W), region=None) -> scalar`` for the configured
    model (the unwrapped ``model`` is needed for the occupancy head's cross-entropy);
    ``region``: the windows' dynamic regions, weighed ``loss.mover_weight`` times in the
    occupancy head's cross-entropy (:mod:`lidarflow.train.movers`; ``None``: unweighted)."""
    warmup = config.data.warmup
    weight = config.loss.occupancy_bce
    if config.loss.mover_weight != 1.0 and (config.model.name != "flownet" or weight <= 0.0):
        raise TrainError(
            "loss.mover_weight weighs the occupancy head's cross-entropy: it needs a flownet "
            "model with loss.occupancy_bce > 0 (e.g. --recipe head_movers)"
        )
    if config.model.name == "deeptracking":
        return _plain(lambda seq, out: deeptracking_loss(seq, out, warmup=warmup))
    if config.model.name == "sogmp":
        return _plain(lambda seq, out: sogmp_loss(seq, out, warmup, config.loss.kl_weight))
    head = model is not None and model.capabilities.occupancy_head
    if weight > 0.0 and not head:
        raise TrainError(
            "loss.occupancy_bce needs a model with an occupancy head: add "
            "--set model.head.hidden_channels=0 (or use --recipe head)"
        )

    def loss(seq: Tensor, out: Tensor, region: Tensor | None = None) -> Tensor:
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
                region=region,
                region_weight=config.loss.mover_weight,
                region_occupied_only=config.loss.mover_cells == "occupied",
            )
        return value

    return loss


def _plain(loss: Callable[[Tensor, Tensor], Tensor]) -> Loss:
    """A loss without a mover weight (``make_loss`` refuses one for these models)."""

    def weighed(seq: Tensor, out: Tensor, region: Tensor | None = None) -> Tensor:
        return loss(seq, out)

    return weighed
