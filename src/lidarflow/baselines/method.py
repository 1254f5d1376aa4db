"""What every streaming next-map predictor is (:class:`Method`: the baselines, the tracker and
evaluate's model method alike), and what it is given each frame."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

__all__ = ["NOTHING_MORE", "FrameInputs", "Method", "Takes"]


@dataclass(frozen=True)
class Takes:
    """What a :class:`Method` takes in ``update`` beside the maps (:class:`FrameInputs`):
    ``motion`` (``motion``, ``next_motion``, ``pace``), ``returns`` (``returns``,
    ``from_pose``), ``subcell``; ``poses_optional``: it may run where a recording has no poses,
    on the motion matched from the scans."""

    motion: bool = False
    poses_optional: bool = False
    returns: bool = False
    subcell: bool = False


@dataclass(frozen=True)
class FrameInputs:
    """What a :class:`Method` is given for one frame beside its maps, each ``None`` where
    unknown or not asked for (:class:`Takes`): ``motion``, the sensor's motion from the previous
    frame to this one (cells and radians, this frame's pose in the previous one's frame);
    ``next_motion``, the true motion to the next frame (only a method that knows the future
    uses it); ``pace``, after a long step in time, the typical step over this one; ``returns``,
    the scan's returns ``(N, 2)`` in metres and ``from_pose``, whether ``motion`` is odometry
    (else matched from the scans, and only checked); ``subcell``, where the returns lie inside
    their cells ``(2, H, W)``."""

    motion: np.ndarray | None = None
    next_motion: np.ndarray | None = None
    pace: float | None = None
    returns: np.ndarray | None = None
    from_pose: bool = True
    subcell: np.ndarray | None = None


#: A frame given with its maps only.
NOTHING_MORE = FrameInputs()


class Method(Protocol):
    """A next-map predictor run one frame at a time: ``update`` takes frame ``t``'s maps
    ``(H, W)`` and what else ``takes`` asks for, and returns the probability map of frame
    ``t + 1``, ``(H, W)`` float32 in [0, 1]. ``reset`` starts a new recording."""

    name: str
    takes: Takes

    def reset(self) -> None: ...

    def update(
        self, occupancy: np.ndarray, visibility: np.ndarray, given: FrameInputs = NOTHING_MORE
    ) -> np.ndarray: ...
