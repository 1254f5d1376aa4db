"""Convolutional LSTM cell (Shi et al. 2015), the recurrent block of SOGMP's encoder.

Equations (``*`` a 'same'-padded convolution over the concatenation ``[x, h]``, ``.`` the
element-wise product), without peephole terms:

    i = sig(W_i * [x, h])    f = sig(W_f * [x, h])    o = sig(W_o * [x, h])
    g = tanh(W_g * [x, h])
    c' = f . c + i . g       h' = o . tanh(c')

The four gates come from one convolution to ``4 * hidden`` channels.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

__all__ = ["ConvLSTMCell"]


class ConvLSTMCell(nn.Module):
    """``forward(x (B, in, H, W), (h, c)) -> (h', c')``, each ``(B, hidden, H, W)``.

    >>> cell = ConvLSTMCell(1, 32)
    >>> x, h = torch.zeros(2, 1, 8, 8), torch.zeros(2, 32, 8, 8)
    >>> h2, c2 = cell(x, (h, h))
    >>> tuple(h2.shape), sum(p.numel() for p in cell.parameters())
    ((2, 32, 8, 8), 38144)
    """

    def __init__(self, in_channels: int, hidden_channels: int, kernel_size: int = 3) -> None:
        super().__init__()
        if kernel_size % 2 == 0:
            raise ValueError(f"kernel_size must be odd ('same' padding), got {kernel_size}")
        self.hidden_channels = hidden_channels
        self.gates = nn.Conv2d(
            in_channels + hidden_channels,
            4 * hidden_channels,
            kernel_size,
            padding=kernel_size // 2,
        )

    def forward(self, x: Tensor, state: tuple[Tensor, Tensor]) -> tuple[Tensor, Tensor]:
        h, c = state
        i, f, o, g = torch.split(self.gates(torch.cat([x, h], dim=1)), self.hidden_channels, 1)
        c = torch.sigmoid(f) * c + torch.sigmoid(i) * torch.tanh(g)
        return torch.sigmoid(o) * torch.tanh(c), c
