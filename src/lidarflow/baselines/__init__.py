"""The baselines every model is reported beside, and the streaming protocol they share.

Used by both :mod:`lidarflow.predict` (the online decision weighs itself against them) and
:mod:`lidarflow.evaluate` (they are scored beside every model), so they live in neither.
"""

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
