"""The experts the online combination weighs: what a model streamed by the engine and the
simple predictors beside it say about the frames ``t + 1 .. t + K``.

- ``model``: the model's own decided maps (its roll-out, without the tracked objects);
- ``tracks``: the tracked objects alone, each moved ``k`` times its velocity;
- ``tracker``: the tracking baseline's map (background where it is, the objects moved);
- ``copy_last``: the last map, moved into the sensor frame ``k`` guessed steps on where the
  sensor moves (the ego-moved map), as it is where it stands still;
- ``temporal_average``: the mean of the last :data:`TA_WINDOW` maps, the same for every ``k``.

The *rare* cells (:func:`rare_cells`) are those whose running occupancy rate, the tracker's
background, is under its threshold: where movers go.
"""

from __future__ import annotations

from collections import deque
from typing import TYPE_CHECKING

import numpy as np

from lidarflow.baselines import TA_WINDOW

if TYPE_CHECKING:
    from lidarflow.predict.engine import Rollout, Step
    from lidarflow.tracking import Tracker

__all__ = ["EXPERTS", "ExpertMaps"]

#: A running rate above this: the cell held something once (a rate never returns to 0).
HELD = 1e-6

#: The experts' names, in the order of their maps.
EXPERTS = ("model", "tracks", "tracker", "copy_last", "temporal_average")


class ExpertMaps:
    """The experts' maps ``(E, K, H, W)`` and rare cells ``(K, H, W)`` after each engine step;
    the engine must run a tracker (its policy carries the tracked objects) and roll out
    ``horizon`` frames."""

    def __init__(self, horizon: int) -> None:
        self.horizon = horizon
        self._recent: deque[np.ndarray] = deque(maxlen=TA_WINDOW)

    def reset(self) -> None:
        self._recent.clear()

    def of(
        self, tracker: Tracker, step: Step, rollout: Rollout, occupancy: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The experts' maps ``(E, K, H, W)`` for the frame just stepped (its ``step`` and
        ``rollout`` ``K`` ahead by an engine that runs ``tracker``; ``occupancy``: its map),
        the rare cells ``(K, H, W)`` and those of them that ever held something."""
        tracks, horizon = step.tracks, self.horizon
        if tracks is None or len(rollout.model_only) < horizon:
            raise ValueError(f"need a step with tracked objects and a roll-out {horizon} ahead")
        self._recent.append(np.asarray(occupancy, np.float32))
        average = np.mean(self._recent, axis=0)
        maps = np.empty((len(EXPERTS), horizon, *average.shape), np.float32)
        maps[0] = rollout.model_only[:horizon]
        background = tracker.background
        assert background is not None
        rare_now = background < tracker.config.background_threshold
        kinds = np.stack([rare_now, rare_now & (background > HELD)]).astype(np.float32)
        rare = np.empty((2, horizon, *average.shape), bool)
        ahead = tracker.ahead(horizon)
        for k in range(1, horizon + 1):
            maps[1, k - 1] = tracks.at(k)
            maps[2, k - 1] = ahead[k - 1]
            maps[3, k - 1] = tracks.moved_to_sensor(occupancy, k)
            maps[4, k - 1] = average
            rare[:, k - 1] = tracks.moved_to_sensor(kinds, k) > 0.5
        return maps, rare[0], rare[1]
