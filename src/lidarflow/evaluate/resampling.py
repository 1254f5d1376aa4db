"""How sure a verdict's margin is: the interval of one method's F1 less another's over the frames
of a recording, by a paired circular block bootstrap.

A recording's frames are not independent draws: consecutive ones share the same people and walls.
So they are resampled in runs of ``ceil(sqrt(F))`` consecutive frames (wrapping at the end), ``F``
frames a draw; both methods take the same frames in a draw (paired), so that what a frame makes
easy or hard for both cancels. Each draw sums the per-frame counts and computes the F1s from the
sums, as the report does (micro-averaging). The interval holds the central :data:`LEVEL` share of
the draws. Seeded: one report computed twice gives the same intervals.

>>> rows = np.array([[3, 1, 0], [2, 0, 1], [4, 1, 1]])  # (tp, fp, fn) per frame
>>> margin_interval(rows, rows, all_cell_f1)
(0.0, 0.0)
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from lidarflow.evaluate.movers import tolerant_f1
from lidarflow.evaluate.scoring import Scorer
from lidarflow.predict.lookahead import f1_from_counts

__all__ = [
    "DRAWS",
    "LEVEL",
    "MARGINS",
    "add_intervals",
    "all_cell_f1",
    "counts_interval",
    "draw_starts",
    "holds",
    "lost_within_noise",
    "margin_interval",
    "mover_interval",
    "paired_interval",
    "resampled_sums",
    "within_noise",
]

#: The share of the draws an interval holds.
LEVEL = 0.9
#: Draws per interval.
DRAWS = 1000


def all_cell_f1(tp: np.ndarray, fp: np.ndarray, fn: np.ndarray) -> np.ndarray:
    """:attr:`~lidarflow.evaluate.metrics.Counts.f1` of counts (arrays alike), elementwise."""
    tp, fp, fn = (np.asarray(v, np.float64) for v in (tp, fp, fn))
    return f1_from_counts(tp, tp + fp, tp + fn)


def draw_starts(frames: int, draws: int = DRAWS, seed: int = 0) -> tuple[np.ndarray, int]:
    """Where each draw's runs start, ``(draws, ceil(frames / block))``, and ``block``, the
    run's length, ``ceil(sqrt(frames))``: a draw takes ``block`` consecutive frames from each
    start (wrapping at the end), its last run cut so that it takes ``frames`` in all."""
    if frames < 1:
        raise ValueError(f"frames must be >= 1, got {frames}")
    block = math.ceil(math.sqrt(frames))
    runs = math.ceil(frames / block)
    return np.random.default_rng(seed).integers(0, frames, (draws, runs)), block


def resampled_sums(rows: np.ndarray, starts: np.ndarray, block: int) -> np.ndarray:
    """``(draws, C)``: the counts ``rows`` ``(F, C)`` summed over each draw's frames
    (:func:`draw_starts`), from running sums, so that memory grows with the draws and runs,
    not with draws times frames."""
    rows = np.asarray(rows, np.int64)
    frames, runs = len(rows), starts.shape[1]
    running = np.zeros((2 * frames + 1, rows.shape[1]), np.int64)
    np.cumsum(np.concatenate([rows, rows]), axis=0, out=running[1:])  # twice: runs wrap
    lengths = np.full(runs, block)
    lengths[-1] = frames - block * (runs - 1)
    return (running[starts + lengths] - running[starts]).sum(axis=1)


def paired_interval(
    rows: np.ndarray,
    baseline_rows: np.ndarray,
    compare: Callable[[np.ndarray, np.ndarray], np.ndarray],
    level: float = LEVEL,
    draws: int = DRAWS,
    seed: int = 0,
) -> tuple[float, float] | None:
    """The central ``level`` interval of ``compare(sums, baseline_sums)`` (each ``(draws,
    C)``, one value a draw; NaN where a draw cannot say) over frames resampled alike for both
    (see the module). ``rows`` and ``baseline_rows`` ``(F, C)``: each frame's counts. ``None``
    without a frame, or where no draw could say."""
    rows, baseline_rows = np.asarray(rows, np.int64), np.asarray(baseline_rows, np.int64)
    if rows.shape != baseline_rows.shape or rows.ndim != 2:
        raise ValueError(f"rows {rows.shape} and baseline rows {baseline_rows.shape} differ")
    if not len(rows):
        return None
    starts, block = draw_starts(len(rows), draws, seed)
    values = compare(
        resampled_sums(rows, starts, block), resampled_sums(baseline_rows, starts, block)
    )
    if np.isnan(values).all():
        return None
    low, high = np.nanquantile(values, [(1 - level) / 2, (1 + level) / 2])
    return float(low), float(high)


def margin_interval(
    rows: np.ndarray,
    baseline_rows: np.ndarray,
    f1: Callable[..., np.ndarray],
    level: float = LEVEL,
    draws: int = DRAWS,
    seed: int = 0,
) -> tuple[float, float] | None:
    """:func:`paired_interval` of ``f1`` of a method's summed counts less ``f1`` of the
    baseline's; ``rows`` in the order ``f1`` takes them (for instance ``(tp, fp, fn)`` with
    :func:`all_cell_f1`)."""

    def margin(mine: np.ndarray, theirs: np.ndarray) -> np.ndarray:
        return f1(*mine.T) - f1(*theirs.T)

    return paired_interval(rows, baseline_rows, margin, level, draws, seed)


def counts_interval(rows: Sequence[int], baseline_rows: Sequence[int]) -> list[float] | None:
    """:func:`margin_interval` of F1 (all cells, or the changed ones), ``[low, high]``, from each
    frame's :class:`~lidarflow.evaluate.metrics.Counts` (flat, ``tp, fp, fn`` a frame)."""
    return _flat_interval(rows, baseline_rows, 3, all_cell_f1)


def mover_interval(rows: Sequence[int], copy_last_rows: Sequence[int]) -> list[float] | None:
    """:func:`margin_interval` of the tolerant mover F1 over copy-last's, ``[low, high]``, from
    each frame's :class:`~lidarflow.evaluate.movers.TolerantCounts` (flat, four a frame)."""
    return _flat_interval(rows, copy_last_rows, 4, tolerant_f1)


def add_intervals(compared: Mapping[str, dict[str, Any]], scorers: Mapping[str, Scorer]) -> None:
    """Give each verdict of :func:`~lidarflow.evaluate.report.against_baselines` (scored by
    ``scorers``, one recording's) its margins' intervals: ``intervals`` ``{"f1",
    "changed_f1", "mover_f1"}`` -> ``[low, high]``, ``None`` where the margin is ``None``."""
    for name, verdict in compared.items():
        mine = scorers[name]
        f1_base, changed_base = (
            scorers[verdict[k]] for k in ("f1_baseline", "changed_f1_baseline")
        )
        verdict["intervals"] = {
            "f1": counts_interval(mine.counts_rows, f1_base.counts_rows),
            "changed_f1": counts_interval(mine.changed_rows, changed_base.changed_rows),
            "mover_f1": None
            if verdict.get("mover_f1_margin") is None
            else mover_interval(mine.mover_rows, scorers["copy_last"].mover_rows),
        }


def holds(interval: Sequence[float] | None, value: float = 0.0) -> bool:
    """Whether ``interval`` ``[low, high]`` holds ``value``, ends included: a margin whose
    interval holds 0 is a tie, the frames being what they are."""
    return interval is not None and interval[0] <= value <= interval[1]


def within_noise(verdict: Mapping[str, Any]) -> list[tuple[str, float, float]]:
    """The margins of ``verdict`` whose interval :func:`holds` 0: ``(name, low, high)``, names
    as in ``intervals``, in their order."""
    return [
        (name, interval[0], interval[1])
        for name, interval in verdict.get("intervals", {}).items()
        if holds(interval)
    ]


#: The verdict's margins by the names ``intervals`` gives them: the verdict's key, and the
#: margin's name for a reader.
MARGINS = {
    "f1": ("f1_margin", "F1"),
    "changed_f1": ("changed_f1_margin", "changed-cell F1"),
    "mover_f1": ("mover_f1_margin", "tolerant mover F1"),
    "mover_f1_horizon": ("mover_f1_horizon_margin", "tolerant mover F1 at the horizon"),
}


def lost_within_noise(verdict: Mapping[str, Any]) -> bool:
    """Whether ``verdict`` is a loss whose every margin at or below 0 has an interval that
    holds 0: a loss the frames cannot tell from a win."""
    if verdict.get("wins") is not False:
        return False
    tied = {name for name, _, _ in within_noise(verdict)}
    failing = {
        name
        for name, (key, _) in MARGINS.items()
        if verdict.get(key) is not None and verdict[key] <= 0
    }
    return bool(failing) and failing <= tied


def _flat_interval(
    rows: Sequence[int], baseline_rows: Sequence[int], width: int, f1: Callable[..., np.ndarray]
) -> list[float] | None:
    interval = margin_interval(
        np.reshape(rows, (-1, width)), np.reshape(baseline_rows, (-1, width)), f1
    )
    return None if interval is None else list(interval)
