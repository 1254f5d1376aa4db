"""The flow-free baselines every model is reported beside: copy the last map, average the
last few, move the whole map by its last rigid shift (each a :class:`~lidarflow.baselines.Method`).
"""

from __future__ import annotations

from collections import deque

import numpy as np

from lidarflow.baselines.method import NOTHING_MORE, FrameInputs, Takes
from lidarflow.compiled import kernel, ready

__all__ = [
    "TA_THRESHOLD",
    "TA_WINDOW",
    "ConstantVelocity",
    "CopyLast",
    "TemporalAverage",
    "best_rigid_shift",
    "shift_map",
]


# The temporal average's default: the majority of the last three maps, the setting of highest
# mean F1 on the development recordings among those that predict changes at all; 0.4, the
# metric's own threshold, leaves the mean unrescaled (docs/research/temporal_average/).
TA_WINDOW = 3
TA_THRESHOLD = 0.4


class CopyLast:
    """Predict that the next map equals the current one."""

    name = "copy_last"
    takes = Takes()

    def reset(self) -> None:
        pass

    def update(
        self, occupancy: np.ndarray, visibility: np.ndarray, given: FrameInputs = NOTHING_MORE
    ) -> np.ndarray:
        return occupancy.astype(np.float32)


class TemporalAverage:
    """Mean of the last ``window`` occupancy maps, occupied where it is >= ``threshold``: the
    mean rescaled piecewise-linearly so that ``threshold`` falls on the metric's 0.4, keeping
    the ranking of cells for the PR curve."""

    name = "temporal_average"
    takes = Takes()

    def __init__(self, window: int = TA_WINDOW, threshold: float = TA_THRESHOLD) -> None:
        if window < 1 or not 0.0 < threshold <= 1.0:
            raise ValueError(f"need window >= 1 and 0 < threshold <= 1, got {window}, {threshold}")
        self.window = window
        self.threshold = threshold
        self._maps: deque[np.ndarray] = deque(maxlen=window)

    def reset(self) -> None:
        self._maps.clear()

    def update(
        self, occupancy: np.ndarray, visibility: np.ndarray, given: FrameInputs = NOTHING_MORE
    ) -> np.ndarray:
        self._maps.append(occupancy.astype(np.float32))
        mean = np.mean(self._maps, axis=0)
        low = mean * (0.4 / self.threshold)
        high = 0.4 + (mean - self.threshold) * (0.6 / max(1.0 - self.threshold, 1e-9))
        return np.where(mean < self.threshold, low, high).astype(np.float32)


def shift_map(image: np.ndarray, d_col: int, d_row: int) -> np.ndarray:
    """Move the content of ``image`` by ``d_col`` columns and ``d_row`` rows (zeros enter).

    >>> shift_map(np.eye(3, dtype=int), 1, 0).tolist()
    [[0, 1, 0], [0, 0, 1], [0, 0, 0]]
    """
    out = np.zeros_like(image)
    h, w = image.shape
    src_r = slice(max(0, -d_row), min(h, h - d_row))
    dst_r = slice(max(0, d_row), min(h, h + d_row))
    src_c = slice(max(0, -d_col), min(w, w - d_col))
    dst_c = slice(max(0, d_col), min(w, w + d_col))
    if src_r.start < src_r.stop and src_c.start < src_c.stop:
        out[dst_r, dst_c] = image[src_r, src_c]
    return out


def best_rigid_shift(previous: np.ndarray, current: np.ndarray, radius: int = 3) -> tuple[int, int]:
    """The integer shift ``(d_col, d_row)`` within ``radius`` that best maps ``previous`` onto
    ``current`` (most overlapping occupied cells; ties prefer the smallest ``|d_col| + |d_row|``,
    then the first in row-major ``(d_row, d_col)`` order). Compiled where available (maps of
    one 2-D shape), the same shift.

    >>> best_rigid_shift(np.tri(4), shift_map(np.tri(4), 1, 0))
    (1, 0)
    """
    prev = np.asarray(previous).astype(bool)
    cur = np.asarray(current).astype(bool)
    fits = prev.shape == cur.shape and cur.ndim == 2 and radius >= 0
    if fits and ready(_shift_loop, prev, cur, radius):
        i = _shift_loop(prev, cur, radius)
        return i % (2 * radius + 1) - radius, i // (2 * radius + 1) - radius
    return _best_rigid_shift_numpy(prev, cur, radius)


def _best_rigid_shift_numpy(prev: np.ndarray, cur: np.ndarray, radius: int) -> tuple[int, int]:
    """:func:`best_rigid_shift` of bool maps in NumPy (the reference)."""
    side = 2 * radius + 1
    steps = np.arange(-radius, radius + 1)
    rows, cols = np.nonzero(prev)
    h, w = cur.shape
    padded = np.zeros((h + 2 * radius, w + 2 * radius), bool)  # np.pad: 4x the time here
    padded[radius : radius + h, radius : radius + w] = cur
    width = padded.shape[1]
    # overlap[i, j]: cells occupied in previous and, moved by (steps[i], steps[j]), in current,
    # gathered at previous's few occupied cells rather than sliding the whole map
    at = (rows + radius) * width + (cols + radius)
    offsets = (steps[:, None] * width + steps[None, :]).ravel()
    overlap = np.count_nonzero(padded.ravel()[at[:, None] + offsets[None, :]], axis=0)
    size = (np.abs(steps)[:, None] + np.abs(steps)[None, :]).ravel()
    # Overlaps are integers and sizes below 4 radius + 1: this orders by (overlap, -size).
    i = int(np.argmax(overlap * (4 * radius + 1) - size))
    return int(steps[i % side]), int(steps[i // side])


@kernel
def _shift_loop(prev: np.ndarray, cur: np.ndarray, radius: int) -> int:
    """:func:`_best_rigid_shift_numpy`'s choice as a flat index ``(d_row + radius) * side +
    d_col + radius`` over bool maps of one shape: the overlaps counted at ``prev``'s occupied
    cells, the first of the largest ``overlap * (4 radius + 1) - |d_row| - |d_col|``."""
    h, w = cur.shape
    side = 2 * radius + 1
    overlap = np.zeros(side * side, np.int64)
    for r in range(h):
        for c in range(w):
            if not prev[r, c]:
                continue
            for i in range(max(0, radius - r), min(side, h - r + radius)):
                rr = r + i - radius
                for j in range(max(0, radius - c), min(side, w - c + radius)):
                    if cur[rr, c + j - radius]:
                        overlap[i * side + j] += 1
    best, chosen = 0, 0
    for k in range(side * side):
        score = overlap[k] * (4 * radius + 1) - abs(k // side - radius) - abs(k % side - radius)
        if k == 0 or score > best:
            best, chosen = score, k
    return chosen


class ConstantVelocity:
    """Extrapolate the scene's last rigid motion: find the integer shift that best maps the
    previous map onto the current one, and apply it once more.

    Flow-free and whole-map: it captures a moving platform's translation (and is copy-last when
    nothing moves), not individual people. Rotation is not modelled.
    """

    name = "constant_velocity"
    takes = Takes()

    def __init__(self, radius: int = 3) -> None:
        self.radius = radius
        self._previous: np.ndarray | None = None

    def reset(self) -> None:
        self._previous = None

    def update(
        self, occupancy: np.ndarray, visibility: np.ndarray, given: FrameInputs = NOTHING_MORE
    ) -> np.ndarray:
        shift = (0, 0)
        if self._previous is not None:
            shift = best_rigid_shift(self._previous, occupancy, self.radius)
        self._previous = occupancy.copy()
        return shift_map(occupancy.astype(np.float32), *shift)
