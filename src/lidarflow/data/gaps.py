"""Gaps in a stream of scans: where the next scan is not the next frame.

The one rule that training (:mod:`lidarflow.data.sequences`), the streaming evaluation and
``lidarflow info`` apply: a step longer than ``max_gap_periods`` times the stream's typical step
(:mod:`lidarflow.stamps`), forwards or backwards. A stamp equal to the one before or a little
before it (two scans handed over out of order) is no gap.
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
