"""Table I of the paper: the flow network (design notes section 4).

    input (O, V)       2 x H x W
    conv0              3x3, 16 ch, d 1, p 1, ReLU
    gru0 / gru1 / gru2 ConvGRU 16 ch, 3x3, dilation 1 / 2 / 4, 'same' padding
    conv_flow          3x3, 4 ch, d 1, p 1   -> B_col, B_row, F_col, F_row (cells), linear

The paper names no activation outside the GRUs: conv_flow is linear (flow is unbounded, signed);
after conv0 a ReLU, without which conv0 would merely compose with each gate's ``W_x*`` into one
linear filter. ``FlowConfig.zero_init`` starts the flow head at zero, so the untrained net is
copy-last. Every layer is a 'same' convolution: the grid size is free.
"""

from __future__ import annotations

from torch import Tensor, nn

from lidarflow.models.config import FlowConfig
from lidarflow.models.convgru import ConvGRUCell

__all__ = ["FlowNetwork"]


class FlowNetwork(nn.Module):
    """``(maps (B, 2, H, W), states) -> (flow (B, 4, H, W), new states)``, one state per GRU.

    >>> import torch
    >>> net = FlowNetwork(FlowConfig())
    >>> states = tuple(torch.zeros(1, 16, 12, 10) for _ in range(3))
    >>> flow, states = net(torch.zeros(1, 2, 12, 10), states)
    >>> tuple(flow.shape), len(states), sum(p.numel() for p in net.parameters())
    ((1, 4, 12, 10), 3, 42500)
    """

    def __init__(self, config: FlowConfig) -> None:
        super().__init__()
        k, hidden = config.kernel_size, config.hidden_channels
        self.conv0 = nn.Conv2d(2, hidden, k, padding=k // 2)
        self.act0 = nn.ReLU()
        self.grus = nn.ModuleList(
            ConvGRUCell(hidden, hidden, k, dilation=d) for d in config.dilations
        )
        self.conv_flow = nn.Conv2d(hidden, 4, k, padding=k // 2)
        if config.zero_init:
            nn.init.zeros_(self.conv_flow.weight)
            nn.init.zeros_(self.conv_flow.bias)

    def state_channels(self) -> tuple[int, ...]:
        return tuple(cell.hidden_channels for cell in self.grus)

    def forward(
        self, maps: Tensor, states: tuple[Tensor, ...]
    ) -> tuple[Tensor, tuple[Tensor, ...]]:
        x = self.act0(self.conv0(maps))
        new_states = []
        for cell, y_prev in zip(self.grus, states, strict=True):
            x = cell(x, y_prev)
            new_states.append(x)
        return self.conv_flow(x), tuple(new_states)
