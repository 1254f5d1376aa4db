"""LiDAR-FlowNet: the flow network of Table I, and optionally an occupancy head on its warp.

Output per step, in cells: ``B_col, B_row, F_col, F_row`` with ``O^{t+1}(p) = O^t(p + B(p))``
and ``O^t(p) = O^{t+1}(p + F(p))`` (design notes section 3); with the head a fifth channel, its
residual logit ``r``. The next map's probability is ``clamp(W(O^t, B^t), 0, 1)``, or with the
head ``sigmoid(g * W(O^t, B^t) + r)``.

Without the flow network (``flow=None``; ``docs/research/flow_share/``) the step is the head
alone: the four flow channels are zero (``W(O^t, 0) = O^t``) but kept, so that the ego-motion
wrapper, the streaming engine and the exported graph are those of any head model.
"""

from __future__ import annotations

import torch
from torch import Tensor

from lidarflow.models.config import Capabilities
from lidarflow.models.flow import FlowNetwork
from lidarflow.models.head import OccupancyHead
from lidarflow.models.recurrent import RecurrentMapModel
from lidarflow.ops.warp import warp

__all__ = ["LidarFlowNet"]


class LidarFlowNet(RecurrentMapModel):
    """``step((O, V) (B, C, H, W), state) -> (out (B, 4 or 5, H, W), state)``. State: one
    ``(B, hidden, H, W)`` tensor per GRU, then the head's memories, if any.

    >>> import torch
    >>> from lidarflow.models.config import FlowConfig
    >>> net = LidarFlowNet(FlowNetwork(FlowConfig()))
    >>> flow, state = net.step(torch.zeros(1, 2, 12, 10), net.init_state(1, 12, 10))
    >>> tuple(flow.shape), len(state), sum(p.numel() for p in net.parameters())
    ((1, 4, 12, 10), 3, 42500)
    """

    def __init__(self, flow: FlowNetwork | None, head: OccupancyHead | None = None) -> None:
        super().__init__()
        if flow is None and head is None:
            raise ValueError("a flownet without a flow network needs an occupancy head")
        self.flow = flow
        self.head = head
        self.out_channels = 4 if head is None else 5
        subcell = head is not None and head.config.subcell_input
        self.input_channels = 4 if subcell else 2

    @property
    def capabilities(self) -> Capabilities:
        return Capabilities(
            self.input_channels,
            self.out_channels,
            flow=self.flow is not None,
            occupancy_head=self.head is not None,
        )

    def state_channels(self) -> tuple[int, ...]:
        grus = () if self.flow is None else self.flow.state_channels()
        return grus if self.head is None else (*grus, self.head.state_channels)

    def step(self, maps: Tensor, state: tuple[Tensor, ...]) -> tuple[Tensor, tuple[Tensor, ...]]:
        if self.flow is None:
            assert self.head is not None  # __init__ refuses neither
            residual, memory = self.head(maps, state[0])
            b, _, h, w = residual.shape
            return torch.cat([residual.new_zeros(b, 4, h, w), residual], dim=1), (memory,)
        grus = len(self.flow.grus)
        flow, states = self.flow(maps[:, :2], state[:grus])
        if self.head is None:
            return flow, states
        residual, memory = self.head(maps, state[grus])
        return torch.cat([flow, residual], dim=1), (*states, memory)

    def predict_next(self, maps: Tensor, out: Tensor) -> Tensor:
        """``P^{t+1}`` ``(B, 1, H, W)``: the warp, or with the head ``sigmoid`` of
        :meth:`next_logit` (calibrated: no decision offset)."""
        if self.head is None:
            return warp(maps[:, 0:1], out[:, 0:2]).clamp(0.0, 1.0)
        return self.next_logit(maps, out).sigmoid()

    def next_logit(self, maps: Tensor, out: Tensor) -> Tensor:
        """Occupancy head only: ``g * W(O^t, B^t) + r`` ``(B, 1, H, W)``."""
        if self.head is None:
            raise ValueError("next_logit needs a model with an occupancy head")
        if self.flow is None:  # zero flow: W(O, 0) = O (the ego wrapper moves the map itself)
            warped = maps[:, 0:1]
        else:
            warped = warp(maps[:, 0:1], out[:, 0:2]).clamp(0.0, 1.0)
        return self.head.gain * warped + out[:, 4:5]

    def warp_gain(self) -> float | None:
        """The head's gain ``g`` (the online decision weighs the unmoved map by it)."""
        return None if self.head is None else float(self.head.gain.detach())
