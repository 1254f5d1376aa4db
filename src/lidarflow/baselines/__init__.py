"""The baselines every model is reported beside, and the streaming protocol they share: used
by both :mod:`lidarflow.predict` and :mod:`lidarflow.evaluate`, so they live in neither."""

from lidarflow.baselines.ego import CopyLastEgo
from lidarflow.baselines.method import NOTHING_MORE, FrameInputs, Method, Takes
from lidarflow.baselines.simple import (
    TA_THRESHOLD,
    TA_WINDOW,
    ConstantVelocity,
    CopyLast,
    TemporalAverage,
    best_rigid_shift,
    shift_map,
)

__all__ = [
    "NOTHING_MORE",
    "TA_THRESHOLD",
    "TA_WINDOW",
    "ConstantVelocity",
    "CopyLast",
    "CopyLastEgo",
    "FrameInputs",
    "Method",
    "Takes",
    "TemporalAverage",
    "best_rigid_shift",
    "shift_map",
]
