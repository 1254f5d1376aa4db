"""Ego-motion compensation around any recurrent map model (Dequaire et al. 2018).

``EgoCompensated(inner)`` is a :class:`RecurrentMapModel` whose ``step`` also takes the sensor's
own motion, so that the inner network only has to explain the motion of the world:

1. Before each step the recurrent state (made in the frame of ``t - 1``) is rigidly warped into
   the frame of ``t`` with ``motion`` (the pose of frame ``t`` in frame ``t - 1``,
   :mod:`lidarflow.ops.rigid`). Cells that come into view start from the zero state.
2. The inner net runs on ``(O^t, V^t)`` and speaks about the world in frame ``t``: a flow model's
   ``B_in, F_in`` satisfy ``O^{t+1}_t(p) = O^t(p + B_in(p))`` where ``O^{t+1}_t`` is the next map
   seen from the *current* pose.
3. The output is expressed in the frame of ``t + 1`` with ``next_motion`` (frame ``t + 1`` in
   frame ``t``), so predictions, flow and losses are exactly those of an ordinary model and
   compare with ``O^{t+1}`` as recorded:

   - ``B(q) = T(q) + B_in(T(q)) - q`` with ``T`` the change of frame ``t+1 -> t`` in cells
     (``B_in`` sampled bilinearly at ``T(q)``);
   - ``F(p) = T^{-1}(p + F_in(p)) - p`` (exact, ``T^{-1}`` is affine);
   - an occupancy logit (DeepTracking's output, SOGMP's first channel, or the occupancy head's
     residual logit, the fifth channel of a flow model built with ``occupancy_head``) is warped
     rigidly, cells coming into view at the prior logit ``logit(0.02)``; SOGMP's second
     channel (its latent's KL, a statistic of the step) is not moved.

``next_motion`` defaults to the constant-velocity guess ``motion`` (causal: at run time only
poses up to ``t`` are known; training does the same). ``motion=None`` runs the step
uncompensated; ``poses_optional=True`` marks a model trained to run so (docs/guide/ego_motion.md).

Motions are ``(dx, dy, dyaw)`` with ``dx, dy`` in *cells*
(:func:`lidarflow.motion.odometry.metres_to_cells`) and ``dyaw`` in radians.
"""

from __future__ import annotations

import dataclasses

import torch
from torch import Tensor

from lidarflow.models.config import OCCUPANCY_FILL_LOGIT, Capabilities
from lidarflow.models.recurrent import RecurrentMapModel
from lidarflow.ops.rigid import cell_grid, rigid_flow, rigid_warp, transform_cells
from lidarflow.ops.warp import warp

__all__ = ["OCCUPANCY_FILL_LOGIT", "EgoCompensated"]


class EgoCompensated(RecurrentMapModel):
    """``step(maps (B,2,H,W), state, motion (B,3)|None, next_motion (B,3)|None)``; see the module
    docstring. ``forward(seq (B,T,2,H,W), state, motions (B,T,3)|None, next_motions|None)``.

    >>> from lidarflow.models import build_model
    >>> net = EgoCompensated(build_model("flownet"))
    >>> m = torch.tensor([[1.0, 0.0, 0.0]])  # one cell forward
    >>> flow, state = net.step(torch.zeros(1, 2, 8, 6), net.init_state(1, 8, 6), m)
    >>> flow[0, :, 0, 0].tolist()  # untrained: zero world flow, i.e. the ego flow alone
    [0.0, -1.0, 0.0, 1.0]
    """

    ego_motion: bool = True

    def __init__(self, inner: RecurrentMapModel, poses_optional: bool = False) -> None:
        super().__init__()
        self.poses_optional = bool(poses_optional)
        if inner.out_channels not in (1, 2, 4, 5):
            raise ValueError(
                "inner model must output 4 flow channels, 1 logit (and SOGMP's KL: 2) or both "
                f"(5), not {inner.out_channels}"
            )
        self.inner = inner
        self.out_channels = inner.out_channels

    @property
    def input_channels(self) -> int:  # type: ignore[override]
        return self.inner.input_channels

    @property
    def capabilities(self) -> Capabilities:
        inner = self.inner.capabilities
        return dataclasses.replace(inner, ego_motion=True, poses_optional=self.poses_optional)

    def warp_gain(self) -> float | None:
        return self.inner.warp_gain()

    def state_channels(self) -> tuple[int, ...]:
        return self.inner.state_channels()

    def step(  # type: ignore[override]
        self,
        maps: Tensor,
        state: tuple[Tensor, ...],
        motion: Tensor | None = None,
        next_motion: Tensor | None = None,
    ) -> tuple[Tensor, tuple[Tensor, ...]]:
        if motion is not None and state:
            # One warp for all state tensors, in at least fp32: bf16's 8-bit mantissa would put
            # cell coordinates near 100 off by up to half a cell.
            sizes = [s.shape[1] for s in state]
            dtype = state[0].dtype
            work = torch.promote_types(dtype, torch.float32)
            # Exported to ONNX the state is sampled by gathers (see warp_gather).
            tracing = torch.jit.is_tracing()
            moved = rigid_warp(
                torch.cat(state, dim=1).to(work), motion.to(work), gather=tracing
            ).to(dtype)
            state = tuple(torch.split(moved, sizes, dim=1))
        out, state = self.inner.step(maps, state)
        nxt = motion if next_motion is None else next_motion
        if nxt is None:
            return out, state
        return self.to_next_frame(out, nxt), state

    def to_next_frame(self, out: Tensor, next_motion: Tensor) -> Tensor:
        """Express the inner net's output (frame ``t``) in the frame of ``t + 1`` (computed in at
        least fp32, see :meth:`step`)."""
        out = out.to(torch.promote_types(out.dtype, torch.float32))
        next_motion = next_motion.to(out.dtype)
        if self.out_channels == 1:
            return rigid_warp(out, next_motion, fill=OCCUPANCY_FILL_LOGIT)
        if self.out_channels == 2:  # SOGMP's KL channel is a statistic of the step: not moved
            logit = rigid_warp(out[:, :1], next_motion, fill=OCCUPANCY_FILL_LOGIT)
            return torch.cat([logit, out[:, 1:]], dim=1)
        h, w = int(out.shape[-2]), int(out.shape[-1])
        ego = rigid_flow(next_motion, h, w, dtype=out.dtype)
        backward = ego + warp(out[:, 0:2], ego)
        c, r = cell_grid(h, w, out.device, out.dtype)
        c2, r2 = transform_cells(c + out[:, 2], r + out[:, 3], next_motion, h, w, inverse=True)
        forward = torch.stack([c2 - c, r2 - r], dim=1)
        moved = [backward, forward]
        if self.out_channels == 5:
            moved.append(rigid_warp(out[:, 4:5], next_motion, fill=OCCUPANCY_FILL_LOGIT))
        return torch.cat(moved, dim=1)

    def _inner_maps(self, maps: Tensor, out: Tensor) -> Tensor:
        """``maps`` as the inner model's prediction takes them: a head without a flow network
        weighs the map as given, so here it is moved first by the output's flow channels (the
        platform's motion alone)."""
        if self.out_channels != 5 or self.inner.capabilities.flow:
            return maps
        moved = warp(maps[:, 0:1], out[:, 0:2]).clamp(0.0, 1.0)
        return torch.cat([moved, maps[:, 1:]], dim=1)

    def predict_next(self, maps: Tensor, out: Tensor) -> Tensor:
        return self.inner.predict_next(self._inner_maps(maps, out), out)

    def next_logit(self, maps: Tensor, out: Tensor) -> Tensor:
        """The inner occupancy head's logit (its output already in the frame of ``t + 1``)."""
        return self.inner.next_logit(self._inner_maps(maps, out), out)  # type: ignore[attr-defined]

    def forward(  # type: ignore[override]
        self,
        seq: Tensor,
        state: tuple[Tensor, ...] | None = None,
        motions: Tensor | None = None,
        next_motions: Tensor | None = None,
    ) -> tuple[Tensor, tuple[Tensor, ...]]:
        """``step`` over ``seq`` ``(B, T, 2, H, W)`` with ``motions`` ``(B, T, 3)`` (frame ``t``
        in frame ``t - 1``, cells) and optionally ``next_motions`` (default: constant velocity)."""
        if motions is None:
            return super().forward(seq, state)
        if seq.dim() == 5 and motions.shape != (*seq.shape[:2], 3):
            raise ValueError(f"motions must be {(*seq.shape[:2], 3)}, got {tuple(motions.shape)}")
        return self._run(seq, state, motion=motions, next_motion=next_motions)
