"""A recording's per-frame arrays computed a block of frames at a time, as they are read:
the streaming evaluation reads frames in order, so it holds two blocks rather than them all.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, overload

import numpy as np

from lidarflow.data.recording import Recording
from lidarflow.scan import GridSpec

__all__ = [
    "BLOCK_FRAMES",
    "FrameBlocks",
    "Frames",
    "streamed_maps",
    "streamed_subcell",
]

BLOCK_FRAMES = 256  # as Recording rasterizes
#: Per-frame arrays: one array ``(N, ...)``, or any sequence of them (a :class:`FrameBlocks`).
Frames = np.ndarray | Sequence[np.ndarray]


class _Frames(Sequence[Any]):
    """A read-only sequence of frames fetched one at a time by :meth:`_frame`; a slice is a
    list of them."""

    @overload
    def __getitem__(self, t: int) -> Any: ...
    @overload
    def __getitem__(self, t: slice) -> Sequence[Any]: ...
    def __getitem__(self, t: int | slice) -> Any:
        if isinstance(t, slice):
            return [self._frame(i) for i in range(*t.indices(len(self)))]
        return self._frame(t)

    def _frame(self, t: int) -> Any:
        raise NotImplementedError


class FrameBlocks(_Frames):
    """Frames ``0 .. n - 1`` of ``compute(a, b)`` (frames ``[a, b)``, anything indexable),
    computed ``block`` (default :data:`BLOCK_FRAMES`) frames at a time; the two blocks
    computed last are kept."""

    def __init__(
        self, compute: Callable[[int, int], Sequence[Any]], n: int, block: int | None = None
    ) -> None:
        self._compute, self._n, self._block = compute, n, block or BLOCK_FRAMES
        self._kept: dict[int, Sequence[Any]] = {}

    def __len__(self) -> int:
        return self._n

    def _frame(self, t: int) -> Any:
        if t < 0:
            t += self._n
        if not 0 <= t < self._n:
            raise IndexError(f"frame {t} of {self._n}")
        k = t // self._block
        if k not in self._kept:
            if len(self._kept) >= 2:
                del self._kept[next(iter(self._kept))]  # the one computed first
            a = k * self._block
            self._kept[k] = self._compute(a, min(a + self._block, self._n))
        return self._kept[k][t - k * self._block]


class _Channel(_Frames):
    """Channel ``c`` of each frame of ``frames`` (frames ``(C, ...)``)."""

    def __init__(self, frames: FrameBlocks, c: int) -> None:
        self._frames, self._c = frames, c

    def __len__(self) -> int:
        return len(self._frames)

    def _frame(self, t: int) -> Any:
        return self._frames[t][self._c]


def streamed_maps(recording: Recording, grid: GridSpec) -> tuple[Sequence[Any], Sequence[Any]]:
    """``recording.maps(grid)`` (occupancy, visibility), a block at a time."""
    both = FrameBlocks(lambda a, b: np.stack(recording.maps(grid, a, b), axis=1), len(recording))
    return _Channel(both, 0), _Channel(both, 1)


def streamed_subcell(recording: Recording, grid: GridSpec) -> FrameBlocks:
    """``recording.subcell_maps(grid)``, a block at a time."""
    return FrameBlocks(lambda a, b: recording.subcell_maps(grid, a, b), len(recording))
