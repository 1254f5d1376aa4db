"""Gaps in a stream of scans: where the next scan is not the next frame.

A recording's scans can stop for a while (a dropped connection, a paused recording, a driver
restart, two sessions in one bag). The frame after such a gap is not what a one-step prediction
predicts: training cuts its windows there (:mod:`lidarflow.data.sequences`), the streaming
evaluation does not score the step into it (:mod:`lidarflow.evaluate.stream`), and ``lidarflow
info`` lists them, all by this one rule.

The rule is relative to the stream's own rate (scanners run at 5-40 Hz): a step longer than
``max_gap_periods`` times the typical step, forwards or backwards (a clock that jumps back). The
typical step is the median of the last ``HISTORY`` forward steps, long ones included: one gap
does not move a median, and a driver that changes its rate (20 Hz -> 5 Hz) is learnt within
half a history (its first slower steps are gaps; not every one from then on). Until
``MIN_STEPS`` steps are known, the median of all the stream's forward steps stands in, so a gap
in the first steps is found too. A stamp equal to the one before (a driver that does not advance
its stamps) or a little before it (two scans handed over out of order) is no gap.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable

import numpy as np

__all__ = ["HISTORY", "MAX_GAP_PERIODS", "MIN_STEPS", "frames_after_gaps"]

MAX_GAP_PERIODS = 2.5
MIN_STEPS = 3
HISTORY = 50  # forward steps the typical step is the median of


def frames_after_gaps(
    stamps_ns: Iterable[int], max_gap_periods: float = MAX_GAP_PERIODS
) -> list[int]:
    """The indices of the stamps (in stream order) that follow a gap."""
    if not max_gap_periods > 1:
        raise ValueError(f"max_gap_periods must be > 1, got {max_gap_periods}")
    stamps = np.asarray(list(stamps_ns), dtype=np.int64)
    forward = np.diff(stamps)
    forward = forward[forward > 0]
    if forward.size == 0:  # stamps that never advance: no rate, so no gap either
        return []
    overall = float(np.median(forward))
    recent: deque[int] = deque(maxlen=HISTORY)
    after = []
    for i in range(1, len(stamps)):
        step = int(stamps[i] - stamps[i - 1])
        typical = float(np.median(recent)) if len(recent) >= MIN_STEPS else overall
        if abs(step) > max_gap_periods * typical:
            after.append(i)
        if step > 0:
            recent.append(step)
    return after
