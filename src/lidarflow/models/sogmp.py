"""SOGMP (Xie & Dames, "Stochastic Occupancy Grid Map Prediction in Dynamic Scenes", CoRL 2023),
rebuilt on lidarflow's grid and inputs from the paper and the public description of its
architecture (``TempleRAIL/SOGMP``, MIT; facts only, the code is our own; summary in
``docs/guide/training.md``): a ConvLSTM over the last maps, a convolutional encoder to a
Gaussian latent ``2 x H/4 x W/4``, a deconvolution decoder to the next map's logit.

Adapted to lidarflow (differences: ``docs/research/peer_comparison/``):

- **Grid**: any; sides not multiples of 4 are padded with zeros at the far and right edges
  inside the model and the prediction cropped back.
- **Input channels**: occupancy only; with ``visibility_input`` each frame is ``(O, V)``.
- **The window is the recurrent state**: ``(B, window x c, H, W)``, the last ``window`` maps,
  oldest first; the first ``window - 1`` steps of a stream see empty maps.
- **Ego motion** through :class:`~lidarflow.models.egomotion.EgoCompensated`.
- **Output**: channel 0 a logit (bias starting at ``logit(0.02)``); channel 1 the step's
  analytic KL of the latent from the prior divided evenly over the cells (a statistic of the
  step, not moved by the ego-motion wrapper).
- **Mean and samples**: ``step`` in eval mode decodes ``z = mu``; :meth:`sample` decodes ``n``
  draws ``z ~ q(z | past)``.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from lidarflow.models.config import Capabilities
from lidarflow.models.convlstm import ConvLSTMCell
from lidarflow.models.recurrent import RecurrentMapModel

__all__ = ["SOGMP", "kl_to_standard_normal"]

PRIOR_OCCUPANCY = 0.02
#: The encoder halves the grid twice; the decoder doubles it twice.
DOWNSAMPLING = 4


def kl_to_standard_normal(mu: Tensor, log_sd: Tensor) -> Tensor:
    """Element-wise ``KL(N(mu, sd^2) || N(0, 1)) = (mu^2 + sd^2 - 1) / 2 - log sd``.

    >>> kl_to_standard_normal(torch.zeros(2), torch.zeros(2)).tolist()
    [0.0, 0.0]
    """
    return 0.5 * (mu.square() + torch.exp(2.0 * log_sd) - 1.0) - log_sd


class ResidualStack(nn.Module):
    """``layers`` residual layers ``r + BN(1x1(ReLU(BN(3x3(r)))))`` with ``r = ReLU(x)``, then
    a ReLU. The skip carries ``ReLU(x)``, as the published layer's in-place ReLU makes it."""

    def __init__(self, channels: int, hidden: int, layers: int) -> None:
        super().__init__()
        self.layers = nn.ModuleList(
            nn.Sequential(
                nn.Conv2d(channels, hidden, 3, padding=1, bias=False),
                nn.BatchNorm2d(hidden),
                nn.ReLU(),
                nn.Conv2d(hidden, channels, 1, bias=False),
                nn.BatchNorm2d(channels),
            )
            for _ in range(layers)
        )

    def forward(self, x: Tensor) -> Tensor:
        for layer in self.layers:
            x = torch.relu(x)
            x = x + layer(x)
        return torch.relu(x)


class LatentEncoder(nn.Module):
    """The ConvLSTM's last hidden state ``(B, in, H, W)`` -> ``mu, log_sd``, each
    ``(B, latent, H/4, W/4)``: two 4x4 stride-2 convolutions, residual layers, 1x1 heads."""

    def __init__(self, channels: int, hidden: int, residual: int, layers: int, latent: int) -> None:
        super().__init__()
        self.features = nn.Sequential(
            nn.Conv2d(channels, hidden // 2, 4, stride=2, padding=1),
            nn.BatchNorm2d(hidden // 2),
            nn.ReLU(),
            nn.Conv2d(hidden // 2, hidden, 4, stride=2, padding=1),
            nn.BatchNorm2d(hidden),
            ResidualStack(hidden, residual, layers),
        )
        self.mu = nn.Conv2d(hidden, latent, 1)
        self.log_sd = nn.Conv2d(hidden, latent, 1)

    def forward(self, h: Tensor) -> tuple[Tensor, Tensor]:
        x = self.features(h)
        return self.mu(x), self.log_sd(x)


class Decoder(nn.Module):
    """``z (B, latent, H/4, W/4)`` -> next-occupancy logit ``(B, 1, H, W)``: 1x1 to ``hidden``,
    residual layers, two 4x4 stride-2 deconvolutions, a 3x3 convolution."""

    def __init__(self, latent: int, hidden: int, residual: int, layers: int) -> None:
        super().__init__()
        self.net = nn.Sequential(
            nn.Conv2d(latent, hidden, 1),
            ResidualStack(hidden, residual, layers),
            nn.ConvTranspose2d(hidden, hidden // 2, 4, stride=2, padding=1),
            nn.BatchNorm2d(hidden // 2),
            nn.ReLU(),
            nn.ConvTranspose2d(hidden // 2, hidden // 2, 4, stride=2, padding=1),
            nn.BatchNorm2d(hidden // 2),
            nn.ReLU(),
            nn.Conv2d(hidden // 2, 1, 3, padding=1),
        )

    def forward(self, z: Tensor) -> Tensor:
        return self.net(z)


class SOGMP(RecurrentMapModel):
    """``step((O, V) (B, 2, H, W), (window,)) -> ((logit, kl) (B, 2, H, W), (window,))``; see
    the module docstring.

    >>> net = SOGMP().eval()
    >>> out, state = net.step(torch.zeros(1, 2, 14, 11), net.init_state(1, 14, 11))
    >>> tuple(out.shape), tuple(state[0].shape), sum(p.numel() for p in net.parameters())
    ((1, 2, 14, 11), (1, 10, 14, 11), 730245)
    """

    out_channels: int = 2

    def __init__(
        self,
        window: int = 10,
        lstm_channels: int = 32,
        hidden_channels: int = 128,
        residual_channels: int = 64,
        residual_layers: int = 2,
        latent_channels: int = 2,
        visibility_input: bool = False,
        prior_occupancy: float = PRIOR_OCCUPANCY,
    ) -> None:
        super().__init__()
        if window < 1 or lstm_channels < 1 or latent_channels < 1 or residual_layers < 0:
            raise ValueError(
                "SOGMP needs window, lstm_channels and latent_channels >= 1 and "
                f"residual_layers >= 0, got {window}, {lstm_channels}, {latent_channels}, "
                f"{residual_layers}"
            )
        if hidden_channels < 2 or hidden_channels % 2 or residual_channels < 1:
            raise ValueError(
                "SOGMP needs an even hidden_channels >= 2 and residual_channels >= 1, got "
                f"{hidden_channels}, {residual_channels}"
            )
        if not 0.0 < prior_occupancy < 1.0:
            raise ValueError(f"prior_occupancy must be in (0, 1), got {prior_occupancy}")
        self.window = int(window)
        self.frame_channels = 2 if visibility_input else 1
        self.lstm = ConvLSTMCell(self.frame_channels, lstm_channels)
        self.encoder = LatentEncoder(
            lstm_channels, hidden_channels, residual_channels, residual_layers, latent_channels
        )
        self.decoder = Decoder(latent_channels, hidden_channels, residual_channels, residual_layers)
        last = self.decoder.net[-1]
        nn.init.constant_(last.bias, math.log(prior_occupancy / (1.0 - prior_occupancy)))

    @property
    def capabilities(self) -> Capabilities:
        return Capabilities(self.input_channels, self.out_channels, flow=False)

    def state_channels(self) -> tuple[int, ...]:
        return (self.window * self.frame_channels,)

    def encode(self, window: Tensor) -> tuple[Tensor, Tensor]:
        """``mu, log_sd`` of ``q(z | window)`` for a window ``(B, window x c, H, W)``; the
        latent is ``ceil(H / 4) x ceil(W / 4)`` (the ConvLSTM's output padded with zeros at the
        far edge, row 0's side, and the right edge to a multiple of 4; :meth:`decode` crops
        them away)."""
        b, _, h, w = window.shape
        frames = window.reshape(b, self.window, self.frame_channels, h, w)
        hidden = window.new_zeros(b, self.lstm.hidden_channels, h, w)
        cell = hidden
        for t in range(self.window):
            hidden, cell = self.lstm(frames[:, t], (hidden, cell))
        return self.encoder(F.pad(hidden, (0, -w % DOWNSAMPLING, -h % DOWNSAMPLING, 0)))

    def decode(self, z: Tensor, height: int, width: int) -> Tensor:
        """The next-occupancy logit ``(B, 1, height, width)`` decoded from ``z`` (the padding
        of :meth:`encode`, far rows first, cropped away)."""
        logit = self.decoder(z)
        return logit[..., logit.shape[-2] - height :, :width]

    def step(self, maps: Tensor, state: tuple[Tensor, ...]) -> tuple[Tensor, tuple[Tensor, ...]]:
        """Slide ``maps`` into the window, encode it, decode ``z`` (``mu`` in eval mode, a draw
        of ``q`` in training: the reparameterisation), with the KL channel."""
        c = self.frame_channels
        window = torch.cat([state[0][:, c:], maps[:, :c].to(state[0].dtype)], dim=1)
        mu, log_sd = self.encode(window)
        z = mu
        if self.training:
            z = mu + torch.exp(log_sd) * torch.randn_like(mu)
        h, w = int(maps.shape[-2]), int(maps.shape[-1])
        logit = self.decode(z, h, w)
        kl = kl_to_standard_normal(mu, log_sd).sum(dim=(1, 2, 3)) / (h * w)
        kl = kl.to(logit.dtype)[:, None, None, None].expand_as(logit)
        return torch.cat([logit, kl], dim=1), (window,)

    def predict_next(self, maps: Tensor, out: Tensor) -> Tensor:
        """``sigmoid(logit)`` ``(B, 1, H, W)``; ``maps`` is unused (kept for the interface)."""
        return torch.sigmoid(out[:, :1])

    @torch.no_grad()
    def sample(
        self,
        state: tuple[Tensor, ...],
        n: int,
        next_motion: Tensor | None = None,
        generator: torch.Generator | None = None,
    ) -> Tensor:
        """``n`` stochastic predictions ``(n, B, 1, H, W)`` (probabilities) of the map after the
        window in ``state``, each decoded from ``z ~ q(z | past)``, in the frame of the newest
        map; ``next_motion`` ``(B, 3)`` (cells, radians) moves them into the frame of ``t + 1``
        as the ego-motion wrapper moves the mean. Call it in eval mode (batch-norm statistics);
        for a model built with ``ego_motion`` it is ``model.inner.sample``."""
        from lidarflow.models.egomotion import OCCUPANCY_FILL_LOGIT
        from lidarflow.ops.rigid import rigid_warp

        if n < 1:
            raise ValueError(f"n must be >= 1, got {n}")
        mu, log_sd = self.encode(state[0])
        eps = torch.randn((n, *mu.shape), generator=generator, device=mu.device, dtype=mu.dtype)
        z = (mu + torch.exp(log_sd) * eps).flatten(0, 1)
        logit = self.decode(z, *state[0].shape[-2:])
        if next_motion is not None:
            motion = next_motion.to(logit.dtype).repeat(n, 1)
            logit = rigid_warp(logit, motion, fill=OCCUPANCY_FILL_LOGIT)
        return torch.sigmoid(logit).reshape(n, mu.shape[0], 1, *logit.shape[-2:])
