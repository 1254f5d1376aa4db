"""The occupancy head: a per-cell probability of the next map on top of the flow's warp.

Not in the paper. The head keeps exponential moving averages of the occupancy (decays
``HeadConfig.memory_decays``) as recurrent state and from each cell's own past (no neighbours)
gives a residual logit ``r``; the model predicts ``P^{t+1} = sigmoid(g * W(O^t, B^t) + r)`` with
a learnt gain ``g`` (:class:`~lidarflow.models.flownet.LidarFlowNet`). Initialised so that the
untrained model is exactly copy-last at the 0.4 threshold.

Options (measurements: ``docs/research/leave_one_out/``):

- ``constant_velocity_input``: the constant-velocity baseline's prediction
  (:mod:`lidarflow.ops.shift`), with the previous map kept as one more state channel.
- ``shift_memories``: each memory is moved by that shift before its update, so it averages the
  world rather than the sensor's frame; the head sees the memories moved into the next frame.
- ``hidden_channels``: one hidden 1x1 layer and a ReLU (0: none).
- ``visibility_input``: ``V^t``; ``subcell_input``: where the returns lie inside their cells,
  ``(edge, near)`` (:func:`lidarflow.scan.subcell_batch`).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor, nn

from lidarflow.models.config import HeadConfig
from lidarflow.ops.shift import apply_shift, best_shift_kernel

__all__ = ["FREE_PROBABILITY_INIT", "OCCUPIED_PROBABILITY_INIT", "OccupancyHead"]

# Roughly copy-last's: a free cell stays free, an occupied one stays occupied nine times in ten.
FREE_PROBABILITY_INIT = 0.01
OCCUPIED_PROBABILITY_INIT = 0.9


class OccupancyHead(nn.Module):
    """``(maps (B, C, H, W), state) -> (residual logit (B, 1, H, W), new state)``; :attr:`gain`
    is ``g``. ``maps`` are ``(O, V)``, with ``subcell_input`` ``(O, V, edge, near)``. State: the
    memories, then (constant-velocity input) the previous occupancy, in one tensor.

    >>> head = OccupancyHead(HeadConfig(memory_decays=(0.5,), hidden_channels=4))
    >>> r, m = head(torch.zeros(1, 2, 6, 5), torch.zeros(1, head.state_channels, 6, 5))
    >>> tuple(r.shape), tuple(m.shape), sum(p.numel() for p in head.parameters())
    ((1, 1, 6, 5), (1, 1, 6, 5), 18)
    """

    def __init__(self, config: HeadConfig) -> None:
        super().__init__()
        self.config = config
        c = config
        features = 1 + len(c.memory_decays) + int(c.constant_velocity_input)
        features += int(c.visibility_input) + 2 * int(c.subcell_input)
        if c.hidden_channels:
            self.hidden = nn.Conv2d(features, c.hidden_channels, 1)
            self.out = nn.Conv2d(c.hidden_channels, 1, 1)
        else:
            self.out = nn.Conv2d(features, 1, 1)
        free, occupied = (
            math.log(p / (1.0 - p)) for p in (FREE_PROBABILITY_INIT, OCCUPIED_PROBABILITY_INIT)
        )
        nn.init.zeros_(self.out.weight)
        nn.init.constant_(self.out.bias, free)
        self.gain = nn.Parameter(torch.tensor(occupied - free))

    @property
    def state_channels(self) -> int:
        return len(self.config.memory_decays) + int(self.config.constant_velocity_input)

    def forward(self, maps: Tensor, state: Tensor) -> tuple[Tensor, Tensor]:
        c = self.config
        occupancy = maps[:, 0:1]
        k = len(c.memory_decays)
        decays = torch.tensor(c.memory_decays, dtype=maps.dtype, device=maps.device)
        decays = decays.view(1, -1, 1, 1)
        past = state[:, :k]
        if c.constant_velocity_input:
            kernel = best_shift_kernel(state[:, -1:], occupancy)
            if c.shift_memories:
                past = apply_shift(past, kernel)
        memory = decays * past + (1.0 - decays) * occupancy
        features, kept = [occupancy], [memory]
        if c.constant_velocity_input:
            if c.shift_memories:
                # One apply_shift moves the memories and the map into the next frame together.
                moved = apply_shift(torch.cat([memory, occupancy], dim=1), kernel)
                seen, extrapolated = moved[:, :k], moved[:, k:]
            else:
                seen, extrapolated = memory, apply_shift(occupancy, kernel)
            features.extend((seen, extrapolated))
            kept.append(occupancy)
        else:
            features.append(memory)
        if c.visibility_input:
            features.append(maps[:, 1:2])
        if c.subcell_input:
            features.append(maps[:, 2:4])
        x = torch.cat(features, dim=1)
        if c.hidden_channels:
            x = torch.relu(self.hidden(x))
        return self.out(x), torch.cat(kept, dim=1)
