"""Pacing after long steps in time: the guess of the next motion when scans were dropped.

After a step of more than :data:`PACE_ABOVE` typical ones (:mod:`lidarflow.stamps`) the last
motion spans it; the guess is that motion scaled to one typical step. A recording is paced as a
whole (:func:`paces_after_long_steps`), a live stream one stamp at a time (:class:`StepClock`).
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from lidarflow.stamps import PACE_ABOVE, RecentSteps, long_steps

__all__ = ["PACE_ABOVE", "StepClock", "paced_motion", "paces_after_long_steps"]


def paces_after_long_steps(stamps_ns: Iterable[int], above: float = PACE_ABOVE) -> dict[int, float]:
    """``{index: typical step / this step}`` for the stamps that follow a step forwards in time
    longer than ``above`` typical ones (shorter steps are jitter: no pace). A stream that has
    slowed down is paced until its steps agree on the new rate (:class:`RecentSteps`)."""
    return {i: pace for i, pace in long_steps(stamps_ns, above) if pace is not None}


def paced_motion(motion: np.ndarray | None, pace: float | None) -> np.ndarray | None:
    """The guess of the motion to the next frame after a long step: ``motion`` (which spans
    it) times ``pace`` (float32); ``None`` where either is unknown."""
    if motion is None or pace is None:
        return None
    return np.asarray(motion, dtype=np.float32) * np.float32(pace)


class StepClock:
    """:func:`paces_after_long_steps`'s rule on a stream, one stamp at a time; it paces
    nothing until ``MIN_STEPS`` forward steps are known (a stream knows no future)."""

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
        """The stream's step between scans (ns): the typical one once known, before that the
        last forward step, ``None`` before two stamped scans."""
        typical = self._recent.typical()
        return round(typical) if typical is not None else self._last_step

    def update(self, stamp_ns: int) -> float | None:
        """This stamp's pace (typical step / this step) if a long step forwards in time precedes
        it, else ``None``. A stamp of 0 is no stamp: it is passed over, not taken for a jump
        back to 1970."""
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
