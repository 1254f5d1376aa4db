"""Speed options for the recurrent models (channels-last, bf16 autocast, ``torch.compile`` of the
ConvGRU cells or the whole step), kept out of the models so the eager fp32 path stays the
reference; timings: ``docs/guide/training.md``.
"""

from __future__ import annotations

from typing import Literal

import torch

from lidarflow.models.convgru import ConvGRUCell
from lidarflow.models.recurrent import RecurrentMapModel

CompileMode = Literal["none", "cells", "step"]
COMPILE_MODES: tuple[str, ...] = ("none", "cells", "step")


def native_bf16(device: torch.device) -> bool:
    """Whether ``device`` computes bf16 natively: a CUDA device that supports it, or a CPU on
    which oneDNN has bf16 kernels (AVX512 or AMX); elsewhere bf16 autocast is emulated."""
    if device.type == "cuda":
        return bool(torch.cuda.is_available() and torch.cuda.is_bf16_supported())
    if device.type == "cpu":
        try:
            return bool(torch.ops.mkldnn._is_mkldnn_bf16_supported())
        except (AttributeError, RuntimeError):  # a build without oneDNN's query
            return False
    return False


def accelerate(
    model: RecurrentMapModel, channels_last: bool = False, compile: CompileMode = "none"
) -> RecurrentMapModel:
    """Apply speed options in place and return ``model``.

    Args:
        channels_last: store the convolution weights channels-last; ``init_state`` then makes
            channels-last states, so the whole recurrence runs in that layout.
        compile: ``"cells"`` compiles each ConvGRU cell (small graphs, quick to compile),
            ``"step"`` compiles the whole ``step`` (one graph per model); ``"none"`` stays eager.

    bf16 is not set here: wrap the forward pass and loss in ``torch.autocast``.
    """
    if compile not in COMPILE_MODES:
        raise ValueError(f"compile must be one of {COMPILE_MODES}, got {compile!r}")
    if channels_last:
        model.to(memory_format=torch.channels_last)  # type: ignore[call-overload]
    if compile == "cells":
        for cell in model.modules():
            if isinstance(cell, ConvGRUCell):
                cell.compile()
    elif compile == "step":
        # An instance attribute shadows the method; forward() calls self.step, so it follows.
        model.step = torch.compile(model.step)  # type: ignore[method-assign]
    return model
