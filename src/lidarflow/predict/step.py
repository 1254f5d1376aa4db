"""One model step's contract, written once: what a backend takes (:class:`StepInputs`), what
it gives (:class:`StepOutput`), and the :class:`Backend` protocol that every backend follows
(:class:`~lidarflow.predict.backends.TorchBackend`,
:class:`~lidarflow.predict.backends.OnnxBackend`,
:class:`~lidarflow.predict.headstep.HeadStepBackend`) and the engine calls.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple, Protocol

import numpy as np

from lidarflow.models.config import Capabilities

__all__ = ["Backend", "StepInputs", "StepOutput"]


@dataclass(frozen=True, slots=True)
class StepInputs:
    """One step's inputs: ``maps`` ``(1, C, H, W)`` float32 (``C`` the model's
    ``input_channels``, 2 or 4); for an ego-motion model ``motion`` ``(3,)``, the sensor's
    motion since the previous frame (cells and radians, this frame's pose in the previous
    one's frame; ``None``: unknown, the step is not compensated), and ``next_motion``, the guess
    of the motion to the next frame (``None``: ``motion`` again). A model without ego motion
    ignores both."""

    maps: np.ndarray
    motion: np.ndarray | None = None
    next_motion: np.ndarray | None = None


class StepOutput(NamedTuple):
    """One step's outputs: ``probability`` ``(1, 1, H, W)``, the model's own probability of the
    next map (calibrated for an occupancy head: no decision offset); ``out`` ``(1,
    out_channels, H, W)`` (the flow ``B_col, B_row, F_col, F_row`` in cells first, where the
    model has flow channels); ``state``, the recurrent state the next step continues from,
    opaque to the caller (tensors for PyTorch, arrays for onnxruntime and NumPy)."""

    probability: np.ndarray
    out: np.ndarray
    state: Any


class Backend(Protocol):
    """One model step on NumPy arrays: ``init_state`` for a grid, then ``run`` per frame."""

    capabilities: Capabilities
    gain: float | None  # an occupancy head's warp gain (the online decision's unmoved map)
    decision: dict[str, Any] | None  # the policy a file ships with ({"offset", "online"})

    def init_state(self, height: int, width: int) -> Any: ...

    def run(self, inputs: StepInputs, state: Any) -> StepOutput: ...
