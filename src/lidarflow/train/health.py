"""Divergence: a training step's health, and the one line that stops a run that lost it.

A step is healthy where its loss, gradient norm and largest model output are finite and within
``runtime.divergence_limit``.
"""

from __future__ import annotations

import math
from pathlib import Path

import torch
from torch import Tensor

from lidarflow.train import checkpoint as ckpt

__all__ = ["divergence_message", "healthy", "step_health"]


def step_health(
    loss: Tensor, grad_norm: Tensor, out: Tensor, clip: float, limit: float
) -> list[float]:
    """The step's loss, gradient norm and largest output, in one sync. The output counts
    because a flow blown up to 1e30 cells still gives a finite loss (the warp samples zeros)."""
    health = torch.stack(
        [loss.detach().float(), grad_norm.float(), out.detach().float().abs().amax()]
    ).tolist()
    if math.isfinite(clip) and math.isfinite(health[1]):
        health[1] = min(health[1], limit)  # with clipping on, only NaN/inf is fatal
    return health


def healthy(value: float, limit: float) -> bool:
    """Whether one of a step's health figures is finite and within ``limit``."""
    return math.isfinite(value) and abs(value) <= limit


def divergence_message(
    health: list[float],
    limit: float,
    epoch: int,
    step: int,
    steps: int,
    lr: float,
    kernel: int,
    run_dir: Path,
) -> str:
    """The one-line story of a divergence: what went non-finite, where, and what to do."""
    names = ("loss", "gradient norm", "largest model output")
    bad = ", ".join(
        f"{n} {v:.4g}" for n, v in zip(names, health, strict=True) if not healthy(v, limit)
    )
    last = ckpt.latest_epoch(run_dir)
    where = f"the last good checkpoint is epoch {last} in {run_dir}" if last else "none finished"
    return (
        f"training diverged at epoch {epoch + 1}, step {step} of {steps} (lr {lr:.3g}, Gaussian "
        f"size {kernel}): non-finite or absurd (> {limit:.0g}) {bad}; nothing of this epoch "
        f"was saved ({where}); lower --lr, set --grad-clip, or drop --amp"
    )
