"""Pacing after long steps in time: the guess of the next motion when scans were dropped.

A constant-velocity guess of the motion to the next frame is the last motion again. After a long
step in the scans' stamps (a gap, a scan or two dropped: :mod:`lidarflow.data.gaps`' rule, with
:data:`PACE_ABOVE` typical steps) the last motion spans it, and the guess is
that motion scaled to one typical step. A recording is paced as a whole
(:func:`paces_after_long_steps`), a live stream one stamp at a time (:class:`StepClock`).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable
from itertools import islice

import numpy as np

__all__ = [
    "HISTORY",
    "MIN_STEPS",
    "PACE_ABOVE",
    "RATE_STEPS",
    "RecentSteps",
    "StepClock",
    "long_steps",
    "paced_motion",
    "paces_after_long_steps",
]

#: A step longer than this many typical ones paces the next motion guess (a dropped scan is 2).
PACE_ABOVE = 1.5
MIN_STEPS = 3
#: This many steps in a row within a factor :data:`RATE_AGREEMENT` of their median, all longer
#: (or all shorter) than the typical step by more than :data:`PACE_ABOVE` times, are a new rate
#: (their median, not their extremes, so that jittery stamps still agree: with Gaussian jitter of
#: 20 % a halved rate is learnt in a median of 10.5 steps over 20 streams, against 25 comparing
#: the extremes; tests/data/test_gaps.py). Scans dropped at random make such a run too (five
#: single drops in a row): of 200 simulated 1000-frame streams, 31 % at 30 % dropped had one
#: (20 %: 13 %; 10 %: 2 %), each costing about five steps paced wrongly until five typical steps
#: restore the rate.
RATE_STEPS = 5
RATE_AGREEMENT = 1.25
HISTORY = 50  # forward steps the typical step is the median of


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

    def reset(self) -> None:
        self._recent.clear()
        self._last = None

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
        return typical / step if typical is not None and step > self.above * typical else None


def long_steps(
    stamps_ns: Iterable[int], periods: float, backwards: bool = False
) -> list[tuple[int, float | None]]:
    """``(index, typical / step)`` of each step longer than ``periods`` typical ones (with
    ``backwards``, of each step back in time so long too, whose pace is ``None``)."""
    if not periods > 1:
        raise ValueError(f"max_gap_periods must be > 1, got {periods}")
    stamps = np.asarray(list(stamps_ns), dtype=np.int64)
    forward = np.diff(stamps)
    forward = forward[forward > 0]
    if forward.size == 0:  # stamps that never advance: no rate, so no gap either
        return []
    overall = float(np.median(forward))
    recent = RecentSteps()
    after = []
    for i in range(1, len(stamps)):
        step = int(stamps[i] - stamps[i - 1])
        typical = recent.typical(overall)
        if step > periods * typical:
            after.append((i, typical / step))
        elif backwards and -step > periods * typical:
            after.append((i, None))
        recent.add(step)
    return after


class RecentSteps:
    """A stream's typical step: the median of its last ``HISTORY`` forward steps, once
    ``MIN_STEPS`` are known (the one rule of the recording and of the stream).

    A stream that changes its rate (a driver gone from 15 to 5 Hz) would take half a history
    to move the median, every step until then a gap; so where the last :data:`RATE_STEPS` steps
    all differ from the median by more than :data:`PACE_ABOVE` times, the same way, and lie
    within a factor :data:`RATE_AGREEMENT` of their own median, they are the new rate and the
    history restarts from them."""

    def __init__(self) -> None:
        self._steps: deque[int] = deque(maxlen=HISTORY)
        self._typical: float | None = None
        # the typical step before each of the last RATE_STEPS steps came
        self._before: deque[float | None] = deque(maxlen=RATE_STEPS)

    def typical(self, fallback: float | None = None) -> float | None:
        return fallback if self._typical is None else self._typical

    def add(self, step: int) -> None:
        if step <= 0:
            return
        self._steps.append(step)
        self._before.append(self._typical)
        before = self._before[0] if len(self._steps) >= 2 * RATE_STEPS else None
        if before is not None:
            last = list(islice(reversed(self._steps), RATE_STEPS))
            low, high, middle = min(last), max(last), sorted(last)[RATE_STEPS // 2]
            agree = high <= RATE_AGREEMENT * middle and low * RATE_AGREEMENT >= middle
            if agree and (low > PACE_ABOVE * before or high * PACE_ABOVE < before):
                self._steps.clear()
                self._steps.extend(reversed(last))
        self._typical = float(np.median(self._steps)) if len(self._steps) >= MIN_STEPS else None

    def clear(self) -> None:
        self._steps.clear()
        self._before.clear()
        self._typical = None
