"""Training sequences: fixed-length windows of consecutive, evenly spaced frames.

A recording is cut into *segments* at gaps and wherever the sensor changes what it covers (a
beam count alone, as LD06-style drivers vary it, is no change); windows never cross a segment
border. Frames that fit in no window are reported as dropped, never silently lost.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from itertools import pairwise

import numpy as np

from lidarflow.data.info import find_gaps
from lidarflow.data.recording import Recording
from lidarflow.errors import RecordingError
from lidarflow.scan import GridSpec

__all__ = [
    "SequenceReport",
    "SequenceSet",
    "sensor_changes",
    "split_segments",
]


def split_segments(recording: Recording, max_gap_periods: float = 2.5) -> list[tuple[int, int]]:
    """Half-open ``(start, stop)`` frame ranges with no long gap and one sensor."""
    cuts = {0, len(recording)}
    cuts.update(i for i, _ in find_gaps(recording, max_gap_periods))
    cuts.update(sensor_changes(recording))
    edges = sorted(cuts)
    return [(a, b) for a, b in pairwise(edges) if b > a]


def sensor_changes(recording: Recording, beams: float = 2.0) -> list[int]:
    """Frames at which the sensor's range limits change, or its first or last beam's angle by
    more than ``beams`` beams (of the wider spacing); a beam count alone is no change."""
    n = len(recording)
    if n < 2:
        return []
    count = np.diff(recording.offsets).astype(np.float64)
    increment = np.asarray(recording.angle_increment, np.float64)
    first = np.asarray(recording.angle_min, np.float64)
    last = first + (count - 1) * increment
    tolerance = beams * np.maximum(np.abs(increment[1:]), np.abs(increment[:-1]))
    changed = (np.abs(np.diff(first)) > tolerance) | (np.abs(np.diff(last)) > tolerance)
    for limit in (recording.range_min, recording.range_max):
        changed |= np.diff(np.asarray(limit, np.float64)) != 0
    return [int(i) + 1 for i in np.nonzero(changed)[0]]


@dataclass
class SequenceReport:
    """What happened to every frame of every recording when windows were cut."""

    recordings: int = 0
    frames: int = 0
    segments: int = 0
    windows: int = 0
    frames_used: int = 0
    frames_dropped: int = 0
    notes: list[str] = field(default_factory=list)

    def summary(self) -> str:
        return (
            f"{self.windows} sequences from {self.recordings} recordings "
            f"({self.frames} frames in {self.segments} segments; "
            f"{self.frames_dropped} frames dropped)"
        )


class SequenceSet:
    """Windows of ``length`` frames over one or many recordings, rasterized once up front.

    ``set[i]`` is a ``(length, 2, H, W)`` float32 array: channel 0 occupancy, 1 visibility
    (with ``subcell``, channels 2 and 3 are :meth:`~lidarflow.data.Recording.subcell_maps`).
    """

    def __init__(
        self,
        recordings: Sequence[Recording],
        length: int = 20,
        stride: int | None = None,
        grid: GridSpec | None = None,
        max_gap_periods: float = 2.5,
        subcell: bool = False,
    ) -> None:
        if length < 2:
            raise RecordingError(f"a sequence needs at least 2 frames, got length={length}")
        self.length = length
        self.stride = stride or length
        self.grid = grid or GridSpec()
        self.maps: list[np.ndarray] = []
        self.index: list[tuple[int, int]] = []
        report = SequenceReport(recordings=len(recordings))
        for rec_id, recording in enumerate(recordings):
            # (N, C, H, W) bool: 8x smaller than float32
            self.maps.append(recording.stacked_maps(self.grid, subcell=subcell))
            report.frames += len(recording)
            used = np.zeros(len(recording), dtype=bool)
            for a, b in split_segments(recording, max_gap_periods):
                report.segments += 1
                starts = range(a, b - length + 1, self.stride)
                if not starts:
                    name = recording.meta.get("source", f"recording {rec_id}")
                    report.notes.append(
                        f"{name}: frames {a}..{b - 1} ({b - a}) shorter than a sequence"
                    )
                for s in starts:
                    self.index.append((rec_id, s))
                    used[s : s + length] = True
            report.frames_used += int(used.sum())
        report.windows = len(self.index)
        report.frames_dropped = report.frames - report.frames_used
        self.report = report
        if not self.index:
            raise RecordingError(
                f"no sequence of {length} frames fits in the given recordings "
                f"({report.frames} frames in {report.segments} segments); "
                "use longer recordings or a shorter --seq-len"
            )

    def __len__(self) -> int:
        return len(self.index)

    def __getitem__(self, i: int) -> np.ndarray:
        rec_id, start = self.index[i]
        return self.maps[rec_id][start : start + self.length].astype(np.float32)
