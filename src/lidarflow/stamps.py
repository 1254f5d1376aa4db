"""A stream's typical step between scans, and the steps much longer than it.

One rule for gaps (:mod:`lidarflow.data.gaps`) and for dropped scans
(:mod:`lidarflow.motion.pacing`), relative to the stream's own rate: the typical step is the
median of the last :data:`HISTORY` forward steps, and a new rate is learnt once
:data:`RATE_STEPS` steps agree on it. Until :data:`MIN_STEPS` steps are known, the median of all
the stream's forward steps stands in (a recording), or nothing is paced (a live stream).
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
    "RATE_AGREEMENT",
    "RATE_STEPS",
    "RecentSteps",
    "long_steps",
]

#: A step longer than this many typical ones paces the next motion guess (a dropped scan is 2).
PACE_ABOVE = 1.5
MIN_STEPS = 3
#: This many steps in a row within a factor :data:`RATE_AGREEMENT` of their median (not their
#: extremes, so that jittery stamps still agree), all longer (or all shorter) than the typical
#: step by more than :data:`PACE_ABOVE` times, are a new rate.
RATE_STEPS = 5
RATE_AGREEMENT = 1.25
HISTORY = 50  # forward steps the typical step is the median of


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
    ``MIN_STEPS`` are known. A new rate (:data:`RATE_STEPS`) restarts the history from its
    steps, rather than taking half a history to move the median, every step until then a gap."""

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
