"""DeepTracking baseline (Dequaire et al. 2018, "Deep tracking in the wild", after Ondruska &
Posner 2016): a recurrent net that predicts the next occupancy directly.

    input (O, V)     2 x H x W
    encoder          3x3 conv, 16 ch, ReLU
    gru0/gru1/gru2   ConvGRU 16 ch, 3x3, dilation 1 / 2 / 4 (the same cell as LiDAR-FlowNet)
    decoder          3x3 conv over the concatenated states of all three GRUs (48 -> 1 ch)
    output           one logit per cell; ``sigmoid`` gives P(occupied at t + 1)

The same encoder, cells and receptive field as LiDAR-FlowNet and a near-equal budget, so the
comparison isolates "predict occupancy directly" against "predict flow and warp". Left out: the
spatial transformer for ego-motion and the learned static-memory bias map (it would tie the
model to one grid size). The decoder's bias starts at ``logit(0.02)`` ("mostly free").
"""

from __future__ import annotations

import math

import torch
from torch import Tensor, nn

from lidarflow.models.convgru import ConvGRUCell
from lidarflow.models.recurrent import RecurrentMapModel

PRIOR_OCCUPANCY = 0.02


class DeepTracking(RecurrentMapModel):
    """``step((O, V) (B, 2, H, W), state) -> (logit (B, 1, H, W), state)``; three GRU states.

    >>> import torch
    >>> net = DeepTracking()
    >>> logit, state = net.step(torch.zeros(2, 2, 9, 11), net.init_state(2, 9, 11))
    >>> tuple(logit.shape), len(state), sum(p.numel() for p in net.parameters())
    ((2, 1, 9, 11), 3, 42353)
    """

    out_channels: int = 1

    def __init__(
        self,
        in_channels: int = 2,
        hidden_channels: int = 16,
        dilations: tuple[int, ...] = (1, 2, 4),
        kernel_size: int = 3,
        prior_occupancy: float = PRIOR_OCCUPANCY,
    ) -> None:
        super().__init__()
        if not 0.0 < prior_occupancy < 1.0:
            raise ValueError(f"prior_occupancy must be in (0, 1), got {prior_occupancy}")
        pad = kernel_size // 2
        self.encoder = nn.Conv2d(in_channels, hidden_channels, kernel_size, padding=pad)
        self.act = nn.ReLU()
        self.grus = nn.ModuleList(
            ConvGRUCell(hidden_channels, hidden_channels, kernel_size, dilation=d)
            for d in dilations
        )
        self.decoder = nn.Conv2d(
            hidden_channels * len(dilations), self.out_channels, kernel_size, padding=pad
        )
        nn.init.constant_(self.decoder.bias, math.log(prior_occupancy / (1.0 - prior_occupancy)))

    def state_channels(self) -> tuple[int, ...]:
        return tuple(cell.hidden_channels for cell in self.grus)

    def step(self, maps: Tensor, state: tuple[Tensor, ...]) -> tuple[Tensor, tuple[Tensor, ...]]:
        x = self.act(self.encoder(maps))
        new_state = []
        for cell, y_prev in zip(self.grus, state, strict=True):
            x = cell(x, y_prev)
            new_state.append(x)
        return self.decoder(torch.cat(new_state, dim=1)), tuple(new_state)

    def predict_next(self, maps: Tensor, out: Tensor) -> Tensor:
        """``sigmoid(logit)`` ``(B, 1, H, W)``; ``maps`` is unused (kept for the interface)."""
        return torch.sigmoid(out)
