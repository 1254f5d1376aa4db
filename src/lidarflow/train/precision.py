"""Training precision: ``runtime.amp`` is ``none`` (fp32, the reference), ``bf16`` (autocast) or
``auto`` (bf16 where the device computes it natively, fp32 where it would be emulated, slower).
Weights and optimizer state stay fp32 either way.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from typing import Any

import torch

from lidarflow.models.speed import native_bf16

__all__ = ["autocast", "resolve_amp"]


def resolve_amp(amp: str, device: torch.device) -> tuple[bool, str | None]:
    """Whether to train under bf16 autocast for ``runtime.amp`` on ``device``, and a line for
    the log where ``auto`` chose, or ``bf16`` costs time."""
    if amp == "none":
        return False, None
    native = native_bf16(device)
    if amp == "auto":
        if native:
            return True, f"amp auto: bf16 autocast ({device.type} computes bf16 natively)"
        return False, f"amp auto: fp32 (this {device.type} has no native bf16, emulated is slower)"
    if native:
        return True, None
    return True, (
        f"note: this {device.type} has no native bf16: bf16 autocast is emulated and slower "
        "than fp32 here (--amp auto or none trains faster)"
    )


def autocast(bf16: bool, device: torch.device) -> Callable[[], Any]:
    """A factory of the context a training step runs in: bf16 autocast, or nothing."""
    if bf16:
        return lambda: torch.autocast(device.type, dtype=torch.bfloat16)
    return contextlib.nullcontext
