"""Gaps in a stream of scans: where the next scan is not the next frame.

A recording's scans can stop for a while (a dropped connection, a paused recording, a driver
restart, two sessions in one bag). The frame after such a gap is not what a one-step prediction
predicts: training cuts its windows there (:mod:`lidarflow.data.sequences`), the streaming
evaluation does not score the step into it (:mod:`lidarflow.evaluate.stream`), and ``lidarflow
info`` lists them, all by this one rule.

The rule is relative to the stream's own rate (scanners run at 5-40 Hz): a step longer than
``max_gap_periods`` times the median of the recent steps, forwards or backwards (a clock that
jumps back). A stamp equal to the one before (a driver that does not advance its stamps) or a
little before it (two scans handed over out of order) is no gap. The first ``MIN_STEPS`` steps
only learn the rate, and after a gap it is learnt again, so that a driver that changes its rate
(20 Hz -> 5 Hz) reads as one gap, not as one before every scan from then on.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable

import numpy as np

__all__ = ["MAX_GAP_PERIODS", "MIN_STEPS", "frames_after_gaps"]

MAX_GAP_PERIODS = 2.5
MIN_STEPS = 3
_HISTORY = 50  # steps the rate is the median of


def frames_after_gaps(
    stamps_ns: Iterable[int], max_gap_periods: float = MAX_GAP_PERIODS
) -> list[int]:
    """The indices of the stamps (in stream order) that follow a gap."""
    if not max_gap_periods > 1:
        raise ValueError(f"max_gap_periods must be > 1, got {max_gap_periods}")
    steps: deque[int] = deque(maxlen=_HISTORY)
    after: list[int] = []
    last: int | None = None
    for i, stamp in enumerate(stamps_ns):
        stamp = int(stamp)
        if last is not None:
            step = stamp - last
            if len(steps) >= MIN_STEPS and abs(step) > max_gap_periods * np.median(steps):
                after.append(i)
                steps.clear()
            elif step > 0:  # stamps that stand still or step back a little teach no rate
                steps.append(step)
        last = stamp
    return after
