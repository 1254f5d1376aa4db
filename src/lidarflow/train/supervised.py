"""Supervised flow in the training loop (``loss.flow_epe > 0``, the ``supervised_flow`` recipe).

With supervision on, training windows carry the exact ``B^t, F^t``; :func:`take_flow` lifts it
off each batch and :func:`flow_term` adds ``loss.flow_epe`` x
:func:`lidarflow.flow_supervision.window_flow_loss`, measuring moving cells against the windows'
motions (a platform standing still without them).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor

from lidarflow.errors import TrainError
from lidarflow.flow_supervision import window_flow_loss
from lidarflow.train.config import TrainConfig
from lidarflow.train.data import TrainData

__all__ = ["flow_term", "require_flow", "supervised", "take_flow"]


def supervised(config: TrainConfig) -> bool:
    """Whether the run teaches the flow from exact flow."""
    return config.loss.flow_epe > 0.0 and config.model.name == "flownet"


def require_flow(config: TrainConfig, data: TrainData) -> None:
    """Refuse, in one line, a source whose training recordings lack exact flow on the grid."""
    for spec, windows in zip(config.data.sources, data.sources, strict=True):
        forward = windows.flows_forward or [None] * len(windows.flows)
        missing = sum(b is None or f is None for b, f in zip(windows.flows, forward, strict=True))
        if missing:
            raise TrainError(
                f"data source {spec}: {missing} of {len(windows.flows)} recording(s) have no "
                "ground-truth flow on this grid (extras flow_backward and flow_forward), which "
                "loss.flow_epe needs: train on `lidarflow simulate` recordings of the same "
                "--grid/--res, or set loss.flow_epe=0"
            )


def take_flow(batch: Sequence[Tensor]) -> tuple[Tensor | list[Tensor], Tensor]:
    """``[maps, flow, has_flow, *rest]`` -> (``maps`` alone or ``[maps, *rest]``, flow), the
    batch as :func:`lidarflow.train.warm.split_batch` takes it without flow."""
    maps, flow, has_flow, *rest = batch
    if not bool(torch.as_tensor(has_flow).all()):
        raise TrainError("a training window without ground-truth flow reached loss.flow_epe")
    return ([maps, *rest] if rest else maps), flow


def flow_term(
    config: TrainConfig, seq: Tensor, out: Tensor, truth: Tensor, motions: list[Tensor]
) -> Tensor:
    """``loss.flow_epe`` x the window loss of ``out`` against ``truth`` (both on the device)."""
    loss = config.loss
    motion = motions[0].to(seq.device) if motions else None
    # Always in fp32, also under bf16 autocast: end-point errors of a tenth of a cell matter.
    with torch.autocast(seq.device.type, enabled=False):
        value = window_flow_loss(
            seq,
            out.float(),
            truth.to(seq.device).float(),
            motion,
            config.data.warmup,
            loss.flow_epe_moving_weight,
            loss.flow_epe_moving_threshold,
        )
    return loss.flow_epe * value
