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

Grid size is not fixed: every layer is a 'same' convolution. ``forward`` has no data-dependent
Python branching, so ``step`` exports to ONNX unchanged.
"""

from __future__ import annotations

from torch import Tensor, nn

from lidarflow.models.convgru import ConvGRUCell
from lidarflow.models.recurrent import RecurrentMapModel
from lidarflow.ops.warp import warp

ACTIVATIONS = ("relu", "none")


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

    out_channels: int = 4

    def __init__(
        self,
        in_channels: int = 2,
        hidden_channels: int = 16,
        dilations: tuple[int, ...] = (1, 2, 4),
        kernel_size: int = 3,
        conv0_activation: str = "relu",
        zero_init_flow: bool = True,
    ) -> None:
        super().__init__()
        if conv0_activation not in ACTIVATIONS:
            raise ValueError(
                f"conv0_activation must be one of {ACTIVATIONS}, got {conv0_activation!r}"
            )
        pad = kernel_size // 2
        self.hidden_channels = hidden_channels
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
        """``P^{t+1} = clamp(W(O^t, B^t), 0, 1)`` ``(B, 1, H, W)`` from maps ``(B, 2, H, W)``
        and the step's output ``(B, 4, H, W)``."""
        return warp(maps[:, 0:1], out[:, 0:2]).clamp(0.0, 1.0)


def lidar_flownet(**kwargs: object) -> LidarFlowNet:
    """The paper's LiDAR-FlowNet (Table I); keyword arguments override :class:`LidarFlowNet`'s."""
    return LidarFlowNet(**kwargs)  # type: ignore[arg-type]


__all__ = ["LidarFlowNet", "lidar_flownet"]
