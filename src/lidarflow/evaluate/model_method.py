"""A trained model as an evaluation method (streaming, state carried across a recording)."""

from __future__ import annotations

import numpy as np

from lidarflow.models.streaming import StreamingModel

__all__ = ["ModelMethod"]


class ModelMethod:
    """Adapts :class:`StreamingModel` to the :class:`~lidarflow.evaluate.baselines.Method`
    protocol; exposes ``backward_flow`` ``(2, H, W)`` after each update for flow models.

    Ego-motion models (``uses_motion``) take the frame's ``motion`` (cells, this frame in the
    previous one, see :mod:`lidarflow.data.motion`) in ``update``; ``oracle=True`` also takes
    the true ``next_motion`` instead of the causal constant-velocity guess (an upper bound that
    needs the future pose, for evaluation only)."""

    def __init__(self, name: str, stream: StreamingModel, oracle: bool = False) -> None:
        self.name = name
        self.stream = stream
        self.uses_motion = bool(getattr(stream.model, "ego_motion", False))
        self.oracle = oracle and self.uses_motion
        self.backward_flow: np.ndarray | None = None

    def reset(self) -> None:
        self.stream.reset()
        self.backward_flow = None

    def update(
        self,
        occupancy: np.ndarray,
        visibility: np.ndarray,
        motion: np.ndarray | None = None,
        next_motion: np.ndarray | None = None,
    ) -> np.ndarray:
        result = self.stream.step(
            occupancy, visibility, motion, next_motion if self.oracle else None
        )
        self.backward_flow = None if result.flow is None else result.flow[:2]
        return result.probability
