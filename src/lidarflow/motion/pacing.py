"""Pacing after long steps in time: the guess of the next motion when scans were dropped.

A constant-velocity guess of the motion to the next frame is the last motion again. After a long
step in the scans' stamps (a gap, a scan or two dropped: more than :data:`PACE_ABOVE` typical
steps, :mod:`lidarflow.stamps`) the last motion spans it, and the guess is that motion scaled to
one typical step. A recording is paced as a whole
(:func:`paces_after_long_steps`), a live stream one stamp at a time (:class:`StepClock`).
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from lidarflow.stamps import PACE_ABOVE, RecentSteps, long_steps

__all__ = ["PACE_ABOVE", "StepClock", "paced_motion", "paces_after_long_steps"]


def paces_after_long_steps(stamps_ns: Iterable[int], above: float = PACE_ABOVE) -> dict[int, float]:
    """``{index: typical step / this step}`` for the stamps that follow a step forwards in time
    longer than ``above`` typical ones: a gap, or a scan or two dropped.

    A constant-velocity guess of the motion to the next frame is the last motion again; after a
    long step the last motion spans it, and this fraction scales it to one typical step. Steps
    up to ``above`` are the stamps' jitter, not scans missing: no pace. A stream that has slowed
    down (a driver gone from 10 to 5 Hz) is paced until :data:`RATE_STEPS` of its steps agree
    on the new rate (see :class:`RecentSteps`)."""
    return {i: pace for i, pace in long_steps(stamps_ns, above) if pace is not None}


def paced_motion(motion: np.ndarray | None, pace: float | None) -> np.ndarray | None:
    """The guess of the motion to the next frame after a long step: ``motion`` (which spans
    it) times ``pace``; ``None`` where either is unknown (an ego-motion model then takes the last
    motion again, its constant-velocity default)."""
    if motion is None or pace is None:
        return None
    return np.asarray(motion, dtype=np.float32) * np.float32(pace)


class StepClock:
    """:func:`paces_after_long_steps`'s rule on a stream, one stamp at a time (the
    ``Predictor``'s).

    A stream knows no future, so until ``MIN_STEPS`` forward steps are known it paces nothing
    (the recording-wide median that the recording's rule starts from is not known yet).
    """

    def __init__(self, above: float = PACE_ABOVE) -> None:
        if not above > 1:
            raise ValueError(f"above must be > 1, got {above}")
        self.above = above
        self._recent = RecentSteps()
        self._last: int | None = None
        self._last_step: int | None = None

    def reset(self) -> None:
        self._recent.clear()
        self._last = None
        self._last_step = None

    @property
    def step_ns(self) -> int | None:
        """The stream's step between scans so far: the typical one once known, before that the
        last forward step, ``None`` before two stamped scans (what a prediction ``k`` steps
        ahead is stamped with, ``k`` times over)."""
        typical = self._recent.typical()
        return round(typical) if typical is not None else self._last_step

    def update(self, stamp_ns: int) -> float | None:
        """This stamp's pace (typical step / this step) if a long step forwards in time precedes
        it, else ``None``. A stamp of 0 is no stamp (a scan built without one): it is passed
        over, not taken for a jump back to 1970 and forward again."""
        if int(stamp_ns) == 0:
            return None
        last, self._last = self._last, int(stamp_ns)
        if last is None:
            return None
        step = self._last - last
        typical = self._recent.typical()
        self._recent.add(step)
        if step > 0:
            self._last_step = step
        return typical / step if typical is not None and step > self.above * typical else None
