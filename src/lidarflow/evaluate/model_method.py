"""A trained model as an evaluation method (streaming, state carried across a recording)."""

from __future__ import annotations

import numpy as np

from lidarflow.models.streaming import StreamingModel

__all__ = ["ModelMethod"]


class ModelMethod:
    """Adapts :class:`StreamingModel` to the :class:`~lidarflow.evaluate.baselines.Method`
    protocol; exposes ``backward_flow`` ``(2, H, W)`` after each update for flow models."""

    def __init__(self, name: str, stream: StreamingModel) -> None:
        self.name = name
        self.stream = stream
        self.backward_flow: np.ndarray | None = None

    def reset(self) -> None:
        self.stream.reset()
        self.backward_flow = None

    def update(self, occupancy: np.ndarray, visibility: np.ndarray) -> np.ndarray:
        result = self.stream.step(occupancy, visibility)
        self.backward_flow = None if result.flow is None else result.flow[:2]
        return result.probability
