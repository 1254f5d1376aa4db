"""LiDAR-FlowNet, exactly Table I of the paper (design notes section 4).

    input (O, V)      2 x H x W
    conv0             3x3, 16 ch, d 1, p 1       (+ ReLU, see below)
    gru0 / gru1 / gru2 ConvGRU 16 ch, 3x3, dilation 1 / 2 / 4, 'same' padding
    conv_flow         3x3, 4 ch, d 1, p 1        -> B_col, B_row, F_col, F_row (cells), linear

42,500 parameters with the bias choice documented in :mod:`lidarflow.models.convgru`.

Activations: the paper names none outside the GRUs. conv_flow is linear (flow is unbounded,
signed). After conv0 we put a ReLU (``conv0_activation="relu"``, the default; ``"none"`` gives
the purely linear conv0): the paper calls conv0 a feature extractor, and without a non-linearity
conv0 would merely compose with each gate's ``W_x*`` into one larger linear filter. It adds no
parameters, so Table I's count is unchanged.

The flow head starts at zero (``zero_init_flow=True``): the untrained net outputs zero flow, so
its prediction ``W(O^t, 0) = O^t`` is copy-last, the baseline it has to beat (issue 11 measured
this start to train better than a random head).

Occupancy head (``occupancy_head=True``, not in the paper; issue 11). Warping can only move cells
that were seen, and a thresholded warp of a binary map cannot express "this cell flickers" or
"this cell will likely be free". The head adds a fifth output channel, a per-cell residual
logit ``r``, and the prediction becomes ``P^{t+1} = sigmoid(g * W(O^t, B^t) + r)`` with a learnt
gain ``g``. At initialisation ``r`` is the constant logit of :data:`FREE_PROBABILITY_INIT` and
``g`` lifts an occupied cell to :data:`OCCUPIED_PROBABILITY_INIT`, so the untrained net is still
exactly copy-last at the 0.4 threshold, and a cross-entropy does not first have to pull every
free cell down (a symmetric start at 0.05 / 0.95 did: the bias moved faster than the gain and
the first epoch predicted nothing occupied). Trained with a cross-entropy against ``O^{t+1}``
(:attr:`lidarflow.losses.LossConfig.occupancy_bce`) the output is a probability, which is what
the F1-at-0.4 metric and a planner both want. Adds 145 parameters (16 x 9 weights + 1 bias of
the fifth channel) plus the gain.

Grid size is not fixed: every layer is a 'same' convolution. ``forward`` has no data-dependent
Python branching, so ``step`` exports to ONNX unchanged.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor, nn

from lidarflow.models.convgru import ConvGRUCell
from lidarflow.models.recurrent import RecurrentMapModel
from lidarflow.ops.warp import warp

ACTIVATIONS = ("relu", "none")
# Roughly what copy-last's cells do on the development recordings: a free cell stays free,
# an occupied one stays occupied nine times in ten.
FREE_PROBABILITY_INIT = 0.01
OCCUPIED_PROBABILITY_INIT = 0.9


class LidarFlowNet(RecurrentMapModel):
    """LiDAR-FlowNet. ``step((O, V) (B, 2, H, W), state) -> (flow (B, 4, H, W), state)``.

    State: one ``(B, hidden, H, W)`` tensor per GRU (three). Output channels, in cells:
    ``B_col, B_row, F_col, F_row`` with ``O^{t+1}(p) = O^t(p + B(p))`` and
    ``O^t(p) = O^{t+1}(p + F(p))`` (design notes section 3).

    >>> import torch
    >>> net = LidarFlowNet()
    >>> flow, state = net.step(torch.zeros(1, 2, 12, 10), net.init_state(1, 12, 10))
    >>> tuple(flow.shape), len(state), sum(p.numel() for p in net.parameters())
    ((1, 4, 12, 10), 3, 42500)
    """

    out_channels: int = 4  # 5 with the occupancy head (channel 4: residual logit)

    def __init__(
        self,
        in_channels: int = 2,
        hidden_channels: int = 16,
        dilations: tuple[int, ...] = (1, 2, 4),
        kernel_size: int = 3,
        conv0_activation: str = "relu",
        zero_init_flow: bool = True,
        occupancy_head: bool = False,
    ) -> None:
        super().__init__()
        if conv0_activation not in ACTIVATIONS:
            raise ValueError(
                f"conv0_activation must be one of {ACTIVATIONS}, got {conv0_activation!r}"
            )
        pad = kernel_size // 2
        self.hidden_channels = hidden_channels
        self.occupancy_head = occupancy_head
        self.out_channels = 5 if occupancy_head else 4
        self.conv0 = nn.Conv2d(in_channels, hidden_channels, kernel_size, padding=pad)
        self.act0 = nn.ReLU() if conv0_activation == "relu" else nn.Identity()
        self.grus = nn.ModuleList(
            ConvGRUCell(hidden_channels, hidden_channels, kernel_size, dilation=d)
            for d in dilations
        )
        self.conv_flow = nn.Conv2d(hidden_channels, self.out_channels, kernel_size, padding=pad)
        if zero_init_flow:
            nn.init.zeros_(self.conv_flow.weight)
            nn.init.zeros_(self.conv_flow.bias)
        if occupancy_head:
            free, occupied = (
                math.log(p / (1.0 - p)) for p in (FREE_PROBABILITY_INIT, OCCUPIED_PROBABILITY_INIT)
            )
            with torch.no_grad():
                self.conv_flow.weight[4:].zero_()
                self.conv_flow.bias[4:].fill_(free)
            self.warp_gain = nn.Parameter(torch.tensor(occupied - free))

    def state_channels(self) -> tuple[int, ...]:
        return tuple(cell.hidden_channels for cell in self.grus)

    def step(self, maps: Tensor, state: tuple[Tensor, ...]) -> tuple[Tensor, tuple[Tensor, ...]]:
        """One frame: ``maps`` (O, V) ``(B, 2, H, W)`` and the GRU states -> flow and new states."""
        x = self.act0(self.conv0(maps))
        new_state = []
        for cell, y_prev in zip(self.grus, state, strict=True):
            x = cell(x, y_prev)
            new_state.append(x)
        return self.conv_flow(x), tuple(new_state)

    def predict_next(self, maps: Tensor, out: Tensor) -> Tensor:
        """``P^{t+1}`` ``(B, 1, H, W)`` from maps ``(B, 2, H, W)`` and the step's output
        ``(B, C, H, W)``: ``clamp(W(O^t, B^t), 0, 1)``, or with the occupancy head
        ``sigmoid(next_logit)``."""
        if self.occupancy_head:
            return torch.sigmoid(self.next_logit(maps, out))
        return warp(maps[:, 0:1], out[:, 0:2]).clamp(0.0, 1.0)

    def next_logit(self, maps: Tensor, out: Tensor) -> Tensor:
        """Occupancy head only: ``g * W(O^t, B^t) + r`` ``(B, 1, H, W)``."""
        if not self.occupancy_head:
            raise ValueError("next_logit needs a model built with occupancy_head=True")
        warped = warp(maps[:, 0:1], out[:, 0:2]).clamp(0.0, 1.0)
        return self.warp_gain * warped + out[:, 4:5]


def lidar_flownet(**kwargs: object) -> LidarFlowNet:
    """The paper's LiDAR-FlowNet (Table I); keyword arguments override :class:`LidarFlowNet`'s."""
    return LidarFlowNet(**kwargs)  # type: ignore[arg-type]


__all__ = ["LidarFlowNet", "lidar_flownet"]
