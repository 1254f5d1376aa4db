"""A model combined online with the simple predictors (:mod:`lidarflow.online`) as an
evaluation method."""

from __future__ import annotations

import numpy as np

from lidarflow.baselines import NOTHING_MORE, FrameInputs
from lidarflow.evaluate.model_method import ModelMethod
from lidarflow.online.combination import Combination, Combined
from lidarflow.online.stacking import StackingConfig
from lidarflow.predict.engine import Backend
from lidarflow.predict.learning import LearningConfig

__all__ = ["CombinedMethod"]


class CombinedMethod:
    """``model`` (a :class:`~lidarflow.predict.engine.Backend`) streamed with its decision
    policy and the tracker, its experts' maps combined for ``1 .. horizon`` frames ahead:
    ``update`` returns the decided combination one frame ahead, ``ahead(k)`` those ``1 .. k``
    ahead (``k`` up to ``horizon``). With ``learning`` the model's head learns on the stream
    (:class:`~lidarflow.evaluate.model_method.ModelMethod`)."""

    def __init__(
        self,
        name: str,
        model: Backend,
        horizon: int,
        res: float = 0.1,
        decision: dict | None = None,
        config: StackingConfig | None = None,
        learning: LearningConfig | None = None,
    ) -> None:
        record = dict(decision if decision is not None else model.decision or {})
        record["movers"] = True  # the tracker is one of the experts
        self.model = ModelMethod(name, model, res=res, decision=record, learning=learning)
        self.name = name
        self.takes = self.model.takes
        self.combination = Combination(horizon, config)
        self._last: Combined | None = None

    def reset(self) -> None:
        self.model.reset()
        self.combination.reset()
        self._last = None

    def update(
        self, occupancy: np.ndarray, visibility: np.ndarray, given: FrameInputs = NOTHING_MORE
    ) -> np.ndarray:
        self.model.update(occupancy, visibility, given)
        engine, step = self.model.engine, self.model.last
        assert step is not None and engine.tracker is not None
        rollout = engine.roll(step, self.combination.horizon)
        self._last = self.combination.step(engine.tracker, step, rollout, occupancy, visibility)
        return self._last.decided[0]

    def ahead(self, horizon: int) -> list[np.ndarray]:
        if self._last is None:
            raise RuntimeError("ahead() before any update()")
        if horizon > self.combination.horizon:
            raise ValueError(f"combined {self.combination.horizon} ahead, asked for {horizon}")
        return list(self._last.decided[:horizon])
