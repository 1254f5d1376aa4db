"""Convolutional GRU cell of LiDAR-FlowNet (paper eq. 1, design notes section 4).

    f    = sigmoid(W_xf * x + W_yf * y_prev)            update gate
    r    = sigmoid(W_xr * x + W_yr * y_prev)            reset gate
    ybar = tanh(W_xy * x + r . (W_yy * y_prev))          candidate
    y    = f . y_prev + (1 - f) . ybar

``*`` is a ``k x k`` convolution with dilation ``d`` and 'same' padding ``d * (k - 1) / 2``, ``.``
the element-wise product.

Fusion: the six convolutions run as two. ``conv_x`` computes the x-parts of f, r and ybar in one
convolution (``C_in -> 3 C``, output channels in that order), ``conv_y`` the y-parts of f, r and
``W_yy * y_prev`` in another (``C -> 3 C``). The arithmetic and the weights are exactly the six
of the equations (each output-channel block of a fused weight is one ``W``); only the number of
kernel launches and the memory traffic drop.

Biases: one per gate channel, carried by ``conv_x`` (3 C per cell); ``conv_y`` has none. A
second bias on the y-side would be redundant for f and r (two biases added before the same
sigmoid) and is what the paper's parameter count rules out: with one bias per gate the
LiDAR-FlowNet of Table I has exactly 42,500 parameters (304 + 3 x 13,872 + 580), the paper's
"about 42.5 K"; with biases on all six convolutions it would have 42,644.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn


class ConvGRUCell(nn.Module):
    """One ConvGRU layer; ``forward(x (B, C_in, H, W), y_prev (B, C, H, W)) -> y (B, C, H, W)``.

    >>> cell = ConvGRUCell(2, 4, dilation=2)
    >>> y = cell(torch.zeros(1, 2, 8, 8), torch.zeros(1, 4, 8, 8))
    >>> tuple(y.shape), sum(p.numel() for p in cell.parameters())
    ((1, 4, 8, 8), 660)
    """

    def __init__(
        self, in_channels: int, hidden_channels: int, kernel_size: int = 3, dilation: int = 1
    ) -> None:
        super().__init__()
        if kernel_size % 2 != 1:
            raise ValueError(f"kernel_size must be odd for 'same' padding, got {kernel_size}")
        padding = dilation * (kernel_size - 1) // 2
        self.in_channels = in_channels
        self.hidden_channels = hidden_channels
        self.dilation = dilation
        self.conv_x = nn.Conv2d(
            in_channels, 3 * hidden_channels, kernel_size, padding=padding, dilation=dilation
        )
        self.conv_y = nn.Conv2d(
            hidden_channels,
            3 * hidden_channels,
            kernel_size,
            padding=padding,
            dilation=dilation,
            bias=False,
        )

    def forward(self, x: Tensor, y_prev: Tensor) -> Tensor:
        """Advance one time step; shapes in the class docstring."""
        xf, xr, xy = self.conv_x(x).chunk(3, dim=1)
        yf, yr, yy = self.conv_y(y_prev).chunk(3, dim=1)
        f = torch.sigmoid(xf + yf)
        r = torch.sigmoid(xr + yr)
        ybar = torch.tanh(torch.addcmul(xy, r, yy))
        # f . y_prev + (1 - f) . ybar, written as ybar + f . (y_prev - ybar): one op fewer.
        return torch.addcmul(ybar, f, y_prev - ybar)

    def extra_repr(self) -> str:
        return f"{self.in_channels} -> {self.hidden_channels}, dilation={self.dilation}, fused"
