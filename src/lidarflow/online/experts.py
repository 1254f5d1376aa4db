"""The experts the online combination weighs: what a model streamed by the engine and the
simple predictors beside it say about the frames ``t + 1 .. t + K`` (:data:`EXPERTS`, in
docs/guide/online.md), with the rare cells and the region where movers went (:class:`Experts`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from lidarflow.baselines import TA_WINDOW, TemporalAverage
from lidarflow.geometry import rigid_moved

if TYPE_CHECKING:
    from lidarflow.predict.engine import Rollout, Step
    from lidarflow.tracking import Tracker

__all__ = ["EXPERTS", "SELDOM", "ExpertMaps", "Experts"]

#: A cell is *seldom* occupied while occupied in under this share of the frames that saw it:
#: the mover metric's dynamic region (:data:`lidarflow.evaluate.dynamic.SHARE`), counted so far.
SELDOM = 0.05

#: The experts' names, in the order of their maps: the model's decided roll-out without the
#: tracked objects; those objects alone, moved ``k`` times their velocity; the tracking
#: baseline; the last map moved into the sensor frame ``k`` guessed steps on; the temporal
#: average (the same for every ``k``).
EXPERTS = ("model", "tracks", "tracker", "copy_last", "temporal_average")


@dataclass(frozen=True)
class Experts:
    """The experts' maps for ``t + first .. t + K`` ``(E, K - first + 1, H, W)``, their
    ``rare`` cells ``(K - first + 1, H, W)`` bool in the sensor frame then (the tracker's
    background under its threshold), and the ``region`` ``(H, W)`` bool of frame ``t`` where
    movers went, as the mover metric finds it but counted up to ``t``: occupied at least once,
    and in under :data:`SELDOM` of the frames that saw it."""

    maps: np.ndarray
    rare: np.ndarray
    region: np.ndarray


class ExpertMaps:
    """The experts' maps of the frames ``first .. horizon`` ahead after each engine step
    (:class:`Experts`), from an engine that runs a tracker and rolls out ``horizon`` frames.
    The counts of occupied and seen frames per cell follow the scene (moved by the ego
    motion)."""

    def __init__(self, horizon: int, first: int = 1) -> None:
        self.horizon, self.first = horizon, first
        self._average = TemporalAverage()  # its defaults decide at 0.4: the mean as it is
        self._counts: np.ndarray | None = None  # (2, H, W): frames occupied, frames seen

    def reset(self) -> None:
        self._average.reset()
        self._counts = None

    @property
    def nbytes(self) -> int:
        """The bytes of the counts and, at most, the temporal average's maps."""
        if self._counts is None:
            return 0
        height, width = self._counts.shape[1:]
        return self._counts.nbytes + TA_WINDOW * height * width * 4

    def of(
        self,
        tracker: Tracker,
        step: Step,
        rollout: Rollout,
        occupancy: np.ndarray,
        visibility: np.ndarray,
    ) -> Experts:
        """The experts for the frame just stepped: its ``step`` and ``rollout`` ``K`` ahead
        by an engine that runs ``tracker``, its ``occupancy`` and ``visibility``."""
        tracks, horizon, first = step.tracks, self.horizon, self.first
        if tracks is None or len(rollout.model_only) < horizon:
            raise ValueError(f"need a step with tracked objects and a roll-out {horizon} ahead")
        occupied = np.asarray(occupancy) > 0.5
        average = self._average.update(occupied.astype(np.float32), visibility)
        self._count(occupied, np.asarray(visibility) > 0.5, step.motion)
        assert self._counts is not None and tracker.background is not None
        occupied_count, seen = self._counts
        region = (occupied_count > 0) & (occupied_count < SELDOM * seen)
        rare_now = tracker.background < tracker.config.background_threshold
        frames = horizon - first + 1
        maps = np.empty((len(EXPERTS), frames, *average.shape), np.float32)
        maps[0] = rollout.model_only[first - 1 : horizon]
        maps[1] = [tracks.at(k) for k in range(first, horizon + 1)]
        rare = np.empty((frames, *average.shape), bool)
        # the tracker's maps, and the last map and its rare cells moved alike: one pass a k
        beside = np.stack([occupied, rare_now])
        for k, moved in enumerate(tracker.ahead(horizon, beside, first, tracks)):
            maps[2, k], maps[3, k] = moved[0], moved[1]
            rare[k] = moved[2] > 0.5
        maps[4] = average
        return Experts(maps, rare, region)

    def _count(self, occupied: np.ndarray, visible: np.ndarray, motion: np.ndarray | None) -> None:
        if self._counts is None:
            self._counts = np.zeros((2, *occupied.shape))
        elif motion is not None and np.any(motion):
            self._counts = rigid_moved(self._counts, motion)
        self._counts[0] += occupied
        self._counts[1] += visible | occupied
