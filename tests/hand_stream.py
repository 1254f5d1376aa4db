"""A model stepped by hand, one frame at a time, for tests: the reference the streaming engine
(:mod:`lidarflow.predict.engine`) is checked against. Written straight from the model's
``step`` / ``predict_next``, with none of the engine's motion checks or decisions."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from lidarflow.models.recurrent import RecurrentMapModel
from lidarflow.scan import takes_subcell

__all__ = ["HandStream", "StepResult", "model_input"]


def model_input(
    model: RecurrentMapModel,
    occupancy: np.ndarray,
    visibility: np.ndarray,
    subcell: np.ndarray | None = None,
) -> np.ndarray:
    """The float32 maps ``(C, H, W)`` one ``model.step`` takes for one frame: ``(O, V)``, and
    for a model with ``input_channels`` 4 ``subcell`` ``(2, H, W)`` after them (zeros if
    ``None``: what a return at a cell's centre gives, and all a predicted map can say)."""
    maps = [occupancy[None], visibility[None]]
    if takes_subcell(model.input_channels):
        maps.append(np.zeros((2, *occupancy.shape)) if subcell is None else subcell)
    return np.concatenate(maps).astype(np.float32)


@dataclass(frozen=True)
class StepResult:
    """One step's prediction: next-map probability ``(H, W)`` and, for flow models, the flow
    ``(4, H, W)`` in cells (``B_col, B_row, F_col, F_row``), else ``None``."""

    probability: np.ndarray
    flow: np.ndarray | None


class HandStream:
    """Feeds ``(occupancy, visibility)`` frames through ``model.step`` with the state carried.

    ``reset()`` starts a new stream (zero state); the grid size is taken from the first frame
    after a reset.

    Ego-motion models (``model.ego_motion``, :class:`~lidarflow.models.EgoCompensated`) take
    ``motion`` ``(dx, dy, dyaw)`` (cells, radians; this frame in the previous one; ``None``: not
    compensated) and optionally the true ``next_motion`` (default: constant velocity, causal);
    other models ignore both. Models with ``input_channels`` 4 (``subcell_input``) take
    ``subcell`` ``(2, H, W)`` too (:func:`lidarflow.scan.subcell_batch`); ``None`` gives them
    zeros, the value of a return at a cell's centre.
    """

    def __init__(self, model: RecurrentMapModel, device: str | torch.device = "cpu") -> None:
        self.model = model.to(device).eval()
        self.device = torch.device(device)
        self._state: tuple[torch.Tensor, ...] | None = None

    def reset(self) -> None:
        self._state = None

    @torch.inference_mode()
    def step(
        self,
        occupancy: np.ndarray,
        visibility: np.ndarray,
        motion: np.ndarray | None = None,
        next_motion: np.ndarray | None = None,
        subcell: np.ndarray | None = None,
    ) -> StepResult:
        maps = model_input(self.model, occupancy, visibility, subcell)[None]
        x = torch.from_numpy(maps).to(self.device)
        if self._state is None:
            self._state = self.model.init_state(1, maps.shape[-2], maps.shape[-1])
        if getattr(self.model, "ego_motion", False):
            m, n = (
                None if a is None else torch.as_tensor(a, dtype=torch.float32).reshape(1, 3)
                for a in (motion, next_motion)
            )
            out, self._state = self.model.step(x, self._state, m, n)  # type: ignore[call-arg]
        else:
            out, self._state = self.model.step(x, self._state)
        probability = self.model.predict_next(x, out)[0, 0].float().cpu().numpy()
        flow = out[0, :4].float().cpu().numpy() if self.model.out_channels >= 4 else None
        return StepResult(probability, flow)
