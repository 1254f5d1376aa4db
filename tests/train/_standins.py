"""TEMPORARY private stand-ins for lidarflow.models / lidarflow.losses (tests only).

Registered by conftest only when the real modules are missing; removed once the model branch
is merged.
"""

from __future__ import annotations

import sys
import types
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from lidarflow.ops import gaussian_blur, warp


@dataclass
class LossConfig:
    blur_source: bool = True
    blur_target: bool = False
    smoothness: float = 0.0
    visible_only: bool = False
    occupied_weight: float = 1.0
    bce: bool = False
    forward_term: bool = True

    @classmethod
    def paper(cls) -> LossConfig:
        return cls()

    @classmethod
    def blurred_both(cls) -> LossConfig:
        return cls(blur_target=True)


def gaussian_schedule(epoch: int, start: int = 9, step_epochs: int = 25, minimum: int = 1) -> int:
    return max(start - 2 * (epoch // step_epochs), minimum)


def flow_loss(seq, flows, kernel_size, config, warmup=10):
    occ = seq[:, :, 0:1]
    total = 0.0
    count = 0
    for t in range(warmup, seq.shape[1] - 1):
        a, b = occ[:, t], occ[:, t + 1]
        src_a = gaussian_blur(a, kernel_size) if kernel_size > 1 else a
        tgt_b = gaussian_blur(b, kernel_size) if kernel_size > 1 and config.blur_target else b
        total = total + F.mse_loss(warp(src_a, flows[:, t, 0:2]), tgt_b)
        if config.forward_term:
            src_b = gaussian_blur(b, kernel_size) if kernel_size > 1 else b
            tgt_a = gaussian_blur(a, kernel_size) if kernel_size > 1 and config.blur_target else a
            total = total + F.mse_loss(warp(src_b, flows[:, t, 2:4]), tgt_a)
        count += 1
    return total / max(count, 1)


def deeptracking_loss(seq, logits, warmup=10):
    target = seq[:, warmup + 1 :, 0:1]
    return F.binary_cross_entropy_with_logits(logits[:, warmup:-1], target)


class _Net(nn.Module):
    def __init__(self, out_channels: int, flow: bool) -> None:
        super().__init__()
        self.out_channels = out_channels
        self.flow = flow
        self.conv0 = nn.Conv2d(2, 8, 3, padding=1)
        self.gates = nn.Conv2d(16, 16, 3, padding=1)
        self.cand = nn.Conv2d(16, 8, 3, padding=1)
        self.head = nn.Conv2d(8, out_channels, 3, padding=1)
        if flow:
            nn.init.zeros_(self.head.weight)
            nn.init.zeros_(self.head.bias)

    def init_state(self, batch, height, width, device=None, dtype=None):
        return (torch.zeros(batch, 8, height, width, device=device, dtype=dtype),)

    def step(self, maps, state):
        x = torch.relu(self.conv0(maps))
        (h,) = state
        f, r = torch.sigmoid(self.gates(torch.cat([x, h], 1))).chunk(2, 1)
        cand = torch.tanh(self.cand(torch.cat([x, r * h], 1)))
        h = f * h + (1 - f) * cand
        return self.head(h), (h,)

    def forward(self, seq, state=None):
        b, t, _, hh, ww = seq.shape
        if state is None:
            state = self.init_state(b, hh, ww, seq.device, seq.dtype)
        outs = []
        for i in range(t):
            out, state = self.step(seq[:, i], state)
            outs.append(out)
        return torch.stack(outs, 1), state

    def predict_next(self, maps, out):
        if self.flow:
            return warp(maps[:, 0:1], out[:, 0:2]).clamp(0, 1)
        return torch.sigmoid(out)


def build_model(name: str, **kwargs):
    if name == "flownet":
        return _Net(4, True)
    if name == "deeptracking":
        return _Net(1, False)
    raise ValueError(name)


def count_parameters(model):
    return sum(p.numel() for p in model.parameters())


def install() -> None:
    import importlib.util

    if importlib.util.find_spec("lidarflow.losses") is not None:
        return
    losses = types.ModuleType("lidarflow.losses")
    for obj in (LossConfig, gaussian_schedule, flow_loss, deeptracking_loss):
        setattr(losses, obj.__name__, obj)
    sys.modules["lidarflow.losses"] = losses
