"""The sensor's own motion between consecutive frames, from a recording's poses.

``Recording.poses`` is ``(N, 3)`` ``(x, y, yaw)`` in a fixed frame, NaN where unknown. The ego
motion of frame ``t`` is its pose in the frame of ``t - 1`` (``dx`` forward, ``dy`` left in
metres, ``dyaw`` radians; :mod:`lidarflow.ops.rigid`'s convention); where either pose is unknown
it is the identity and not ``known``. Poses taken from the base rather than the scanner can make
compensating worse than none: :class:`OdometryCheck` tells, from the scans alone, whether they
agree.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from lidarflow.geometry import transform_cells

__all__ = [
    "MAX_SPEED",
    "OdometryCheck",
    "cells_in_new_frame",
    "metres_to_cells",
    "pose_jumps",
    "relative_motions",
]

#: Faster than this (m/s) from one scan's pose to the next, the pose jumped (an odometry glitch,
#: a relocalisation): no platform carrying a 2-D scanner drives so fast.
MAX_SPEED = 50.0
#: A pose may move this far (m) however close the stamps (two scans at one stamp, jitter).
_JUMP_SLACK = 1.0


def relative_motions(
    poses: np.ndarray | None, n: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame ego motion ``(N, 3)`` float64 and whether it is known ``(N,)`` bool.

    ``poses=None`` (a recording without odometry) gives ``n`` identity motions, all unknown.

    >>> m, known = relative_motions(np.array([[0, 0, 0], [1, 0, np.pi / 2], [1, 1, np.pi / 2]]))
    >>> np.round(m, 6).tolist(), known.tolist()
    ([[0.0, 0.0, 0.0], [1.0, 0.0, 1.570796], [1.0, 0.0, 0.0]], [False, True, True])
    """
    if poses is None:
        if n is None:
            raise ValueError("relative_motions needs poses or the number of frames")
        return np.zeros((n, 3)), np.zeros(n, dtype=bool)
    poses = np.asarray(poses, dtype=np.float64)
    if poses.ndim != 2 or poses.shape[1] != 3:
        raise ValueError(f"poses must be (N, 3) (x, y, yaw), got {poses.shape}")
    motions = np.zeros_like(poses)
    known = np.zeros(len(poses), dtype=bool)
    if len(poses) < 2:
        return motions, known
    a, b = poses[:-1], poses[1:]
    ok = np.isfinite(a).all(axis=1) & np.isfinite(b).all(axis=1)
    c, s = np.cos(a[:, 2]), np.sin(a[:, 2])
    dx, dy = b[:, 0] - a[:, 0], b[:, 1] - a[:, 1]
    dyaw = np.remainder(b[:, 2] - a[:, 2] + np.pi, 2 * np.pi) - np.pi
    rel = np.stack([c * dx + s * dy, -s * dx + c * dy, dyaw], axis=1)
    motions[1:][ok] = rel[ok]
    known[1:] = ok
    return motions, known


def pose_jumps(
    poses: np.ndarray | None, stamps_ns: np.ndarray, max_speed: float = MAX_SPEED
) -> list[tuple[int, float]]:
    """``(frame, metres)`` for each frame whose pose is further from the last known one before
    it than ``max_speed`` (m/s) drives in the time between their stamps (plus 1 m); frames of
    unknown pose are skipped.

    >>> stamps = np.arange(4) * 100_000_000  # 10 Hz
    >>> pose_jumps(np.array([[0, 0, 0], [0.1, 0, 0], [1000, 1000, 0], [1000.1, 1000, 0]]), stamps)
    [(2, 1414.1)]
    """
    if poses is None or len(poses) < 2:
        return []
    poses = np.asarray(poses, np.float64)
    known = np.flatnonzero(np.isfinite(poses).all(axis=1))
    a, b = known[:-1], known[1:]
    metres = np.hypot(*(poses[b, :2] - poses[a, :2]).T)
    seconds = np.maximum(np.asarray(stamps_ns, np.int64)[b] - stamps_ns[a], 0) / 1e9
    jumped = metres > max_speed * seconds + _JUMP_SLACK
    return [(int(t), round(float(d), 1)) for t, d in zip(b[jumped], metres[jumped], strict=True)]


def metres_to_cells(motions: np.ndarray, res: float) -> np.ndarray:
    """``(dx, dy)`` from metres to cells of size ``res``; ``dyaw`` unchanged (float32)."""
    out = np.asarray(motions, dtype=np.float64).copy()
    out[..., :2] /= res
    return out.astype(np.float32)


def cells_in_new_frame(
    rows: np.ndarray, cols: np.ndarray, motion: np.ndarray, height: int, width: int
) -> tuple[np.ndarray, np.ndarray]:
    """The nearest cells ``(rows, cols)`` (int64) in the new sensor frame of the old frame's
    cells ``rows, cols`` after the sensor moved by ``motion`` ``(dx, dy, dyaw)`` (cells,
    radians): :func:`lidarflow.geometry.transform_cells` old -> new, rounded; they may fall
    outside the ``height x width`` grid."""
    new_cols, new_rows = transform_cells(cols, rows, motion, height, width, inverse=True)
    return np.rint(new_rows).astype(np.int64), np.rint(new_cols).astype(np.int64)


class OdometryCheck:
    """Does the odometry agree with the scans? Causal and label-free: models that may run
    without poses stop compensating while it says no.

    At every step whose motion moves the previous map's occupied cells by at least
    ``min_shift`` cells (median), the cells moved by the motion (nearest cell) and the same
    cells not moved are counted where they land on the current map's occupied cells (cells
    moved off the grid count in neither). The odometry is trusted until ``min_steps`` steps
    are seen, then while, over the last ``window`` steps, the moved cells hit at least as often.

    A pose jump (an odometry reset, a relocalisation) is judged alone: a step that moves the
    cells more than ``jump_factor`` times the recent median plus ``jump_margin`` cells (each per
    typical step of time, ``span``), and whose :meth:`stand_in` explains the current map at
    least twice as well plus ``jump_evidence`` cells, is not compensated and left out of the
    window.

    Units: maps ``(H, W)`` bool, motion ``(dx, dy, dyaw)`` in cells and radians.
    """

    def __init__(
        self,
        min_steps: int = 10,
        window: int = 50,
        min_shift: float = 1.5,
        jump_factor: float = 3.0,
        jump_margin: float = 4.0,
        jump_evidence: int = 3,
    ) -> None:
        self.min_steps = min_steps
        self.min_shift = min_shift
        self.jump_factor = jump_factor
        self.jump_margin = jump_margin
        self.jump_evidence = jump_evidence
        self._moved: deque[int] = deque(maxlen=window)
        self._still: deque[int] = deque(maxlen=window)
        self._shifts: deque[float] = deque(maxlen=window)
        self.reset()

    def reset(self) -> None:
        self._moved.clear()
        self._still.clear()
        self._shifts.clear()
        self._previous: np.ndarray | None = None
        #: Steps judged to be a jump of the poses since the last reset.
        self.jumps = 0
        #: Whether the last step given was judged a jump.
        self.jumped = False
        # the last motion not judged a jump, per typical step of time
        self._per_step: np.ndarray | None = None

    @property
    def trusted(self) -> bool:
        return len(self._moved) < self.min_steps or sum(self._moved) >= sum(self._still)

    def update(self, occupancy: np.ndarray, motion: np.ndarray | None, span: float = 1.0) -> bool:
        """Feed this frame's map and motion (``None``: unknown) and the step's length in typical
        steps (``span``: more than 1 after a gap or dropped scans); whether to compensate it."""
        current = np.asarray(occupancy, dtype=bool)
        previous, self._previous = self._previous, current
        self.jumped = False
        if previous is None or motion is None or previous.shape != current.shape:
            return self.trusted
        rows, cols = np.nonzero(previous)
        span = max(1.0, span)
        if rows.size == 0:  # nothing to judge the step by
            self._per_step = np.asarray(motion, dtype=np.float32) / np.float32(span)
            return self.trusted
        r2, c2, inside = _moved(rows, cols, motion, current.shape)
        shift = float(np.median(np.hypot(r2 - rows, c2 - cols)))
        moved = int(current[r2[inside], c2[inside]].sum())
        still = int(current[rows[inside], cols[inside]].sum())
        # An outlier has recent steps to be one against, so a stand-in to weigh it by.
        stand_in = self.stand_in(span) if self._is_outlier(shift / span) else None
        evidence = 2 * moved + self.jump_evidence
        if stand_in is not None and _hits(rows, cols, current, stand_in) >= evidence:
            self.jumps += 1
            self.jumped = True
            return False
        self._per_step = np.asarray(motion, dtype=np.float32) / np.float32(span)
        self._shifts.append(shift / span)
        if not inside.any() or shift < self.min_shift:
            return self.trusted
        self._moved.append(moved)
        self._still.append(still)
        return self.trusted

    def stand_in(self, span: float = 1.0) -> np.ndarray | None:
        """The motion to take for a step judged a jump that is ``span`` typical steps long: the
        last accepted one's per typical step, times ``span`` (``None`` before any)."""
        return None if self._per_step is None else self._per_step * np.float32(max(1.0, span))

    def _is_outlier(self, per_step: float) -> bool:
        if not self._shifts:  # nothing to compare the first step with
            return False
        return per_step > self.jump_factor * float(np.median(self._shifts)) + self.jump_margin


def _moved(
    rows: np.ndarray, cols: np.ndarray, motion: np.ndarray, shape: tuple[int, int]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`cells_in_new_frame` of the cells, and which of them land on the grid."""
    h, w = shape
    r2, c2 = cells_in_new_frame(rows, cols, motion, h, w)
    return r2, c2, (r2 >= 0) & (r2 < h) & (c2 >= 0) & (c2 < w)


def _hits(rows: np.ndarray, cols: np.ndarray, current: np.ndarray, motion: np.ndarray) -> int:
    """How many of the cells, moved by ``motion``, land on ``current``'s occupied cells."""
    r2, c2, inside = _moved(rows, cols, motion, current.shape)
    return int(current[r2[inside], c2[inside]].sum())
