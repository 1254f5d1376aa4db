"""Gaps in a stream of scans: where the next scan is not the next frame.

A recording's scans can stop for a while (a dropped connection, a paused recording, a driver
restart, two sessions in one bag). The frame after such a gap is not what a one-step prediction
predicts: training cuts its windows there (:mod:`lidarflow.data.sequences`), the streaming
evaluation does not score the step into it (:mod:`lidarflow.evaluate.stream`), and ``lidarflow
info`` lists them, all by this one rule.

The rule: a step longer than ``max_gap_periods`` times the stream's typical step
(:mod:`lidarflow.stamps`), forwards or backwards (a clock that jumps back); after a driver changes
its rate, its first slower steps are gaps. A stamp equal to the one before or a little before it
(two scans handed over out of order) is no gap.
"""

from __future__ import annotations

from collections.abc import Iterable

from lidarflow.stamps import long_steps

__all__ = ["MAX_GAP_PERIODS", "frames_after_gaps"]

MAX_GAP_PERIODS = 2.5


def frames_after_gaps(
    stamps_ns: Iterable[int], max_gap_periods: float = MAX_GAP_PERIODS
) -> list[int]:
    """The indices of the stamps (in stream order) that follow a gap."""
    return [i for i, _ in long_steps(stamps_ns, max_gap_periods, backwards=True)]
