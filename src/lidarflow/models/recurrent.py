"""The interface every map-prediction model of lidarflow offers (train, evaluate and predict code
depends on it; see :mod:`lidarflow.models`).

- ``step(maps (B, 2, H, W), state) -> (out (B, C, H, W), state)``: one frame, for streaming;
  ``forward`` runs it over ``(B, T, 2, H, W)``.
- ``predict_next(maps, out) -> (B, 1, H, W)``: the probability of each cell in the next frame.

Maps are ``(O, V)``: channel 0 occupancy, channel 1 visibility, values in {0, 1}.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from lidarflow.models.config import Capabilities


class RecurrentMapModel(nn.Module):
    """Base of the recurrent map predictors: state handling and the sequence loop."""

    out_channels: int
    #: Channels of the maps ``step`` takes (``(O, V)``; a model may ask for more, see
    #: :attr:`lidarflow.models.flownet.LidarFlowNet.input_channels`).
    input_channels: int = 2

    @property
    def capabilities(self) -> Capabilities:
        """What the model takes and gives (the streaming engine reads this, not attributes)."""
        return Capabilities(self.input_channels, self.out_channels, flow=self.out_channels >= 4)

    def warp_gain(self) -> float | None:
        """An occupancy head's warp gain ``g``; ``None`` for a model without one."""
        return None

    def state_channels(self) -> tuple[int, ...]:
        """Channels of each state tensor, in state order."""
        raise NotImplementedError

    def step(self, maps: Tensor, state: tuple[Tensor, ...]) -> tuple[Tensor, tuple[Tensor, ...]]:
        raise NotImplementedError

    def predict_next(self, maps: Tensor, out: Tensor) -> Tensor:
        raise NotImplementedError

    def init_state(
        self,
        batch: int,
        height: int,
        width: int,
        device: torch.device | str | None = None,
        dtype: torch.dtype | None = None,
    ) -> tuple[Tensor, ...]:
        """Zero state ``(batch, c, height, width)`` per state tensor; device and dtype default
        to the model's parameters'. The memory format follows the convolution weights', so a
        model moved to ``torch.channels_last`` runs its recurrence in channels-last throughout
        (no layout conversion per step)."""
        ref = next(p for p in self.parameters() if p.dim() == 4)
        device = ref.device if device is None else device
        dtype = ref.dtype if dtype is None else dtype
        channels_last = ref.is_contiguous(memory_format=torch.channels_last) and not (
            ref.is_contiguous()
        )
        fmt = torch.channels_last if channels_last else torch.contiguous_format
        return tuple(
            torch.zeros(batch, c, height, width, device=device, dtype=dtype).contiguous(
                memory_format=fmt
            )
            for c in self.state_channels()
        )

    def forward(
        self, seq: Tensor, state: tuple[Tensor, ...] | None = None
    ) -> tuple[Tensor, tuple[Tensor, ...]]:
        """Run ``step`` over ``seq`` ``(B, T, 2, H, W)``; returns ``(B, T, C, H, W)`` and the state
        after the last frame. ``state=None`` starts from zeros."""
        return self._run(seq, state)

    def _run(
        self, seq: Tensor, state: tuple[Tensor, ...] | None, **per_frame: Tensor | None
    ) -> tuple[Tensor, tuple[Tensor, ...]]:
        """:meth:`forward`, each step also given ``per_frame``'s ``(B, T, ...)`` tensors at its
        frame (``None`` as ``None``)."""
        if seq.dim() != 5:
            raise ValueError(f"seq must be (B, T, C, H, W), got {tuple(seq.shape)}")
        b, t, _, h, w = seq.shape
        if state is None:
            state = self.init_state(b, h, w, device=seq.device, dtype=seq.dtype)
        outs = []
        for i in range(t):
            extra = {k: None if v is None else v[:, i] for k, v in per_frame.items()}
            out, state = self.step(seq[:, i], state, **extra)
            outs.append(out)
        return torch.stack(outs, dim=1), state
