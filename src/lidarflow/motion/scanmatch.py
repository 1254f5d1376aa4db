"""The sensor's own motion from its scans, for recordings and robots without odometry.

Correlative matching of two consecutive occupancy maps (:mod:`.correlative`), refined to a
fraction of a cell and of a turn step by a parabola through the peak. A match counts only when
it explains the current map clearly better than standing still (:data:`MIN_GAIN`); otherwise
there is no motion to report (``None``). Where the returns are at hand, :class:`ScanOdometry`
refines the match on them (:mod:`lidarflow.motion.icp`) and so also finds motions too slow to
move cells (``docs/research/scan_odometry/``).

Motion convention: :mod:`lidarflow.ops.rigid`'s, ``(dx, dy, dyaw)`` in cells and radians, this
frame's pose in the previous one's.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from lidarflow.motion.correlative import MAX_SHIFT, YAWS, correlate
from lidarflow.motion.icp import Alignment, Reference, align, fit
from lidarflow.motion.odometry import OdometryCheck

__all__ = [
    "MAX_SHIFT",
    "MIN_GAIN",
    "MIN_TRAVEL",
    "STILL_FIT",
    "STILL_WINDOW",
    "TURN_REACH",
    "YAWS",
    "ScanOdometry",
    "checked_motion",
    "compose",
    "match_maps",
    "scan_motions",
]

#: A match must land this many times the cells standing still does (and 3 cells more).
MIN_GAIN = 1.05
_MIN_EXTRA_CELLS = 3.0
#: Frames over which a platform refined on its returns must have travelled...
STILL_WINDOW = 10
#: ... this many cells (a turn counted at TURN_REACH cells, half the default grid's width).
MIN_TRAVEL = 0.5
TURN_REACH = 50.0
#: ... and standing still must pair this share of the returns fewer, or leave them this many
#: times further from the surface, than the travel found: where the scene cannot tell, the
#: travel is the steps' noise. A motion the maps show must pass the same test against the
#: previous frame's returns (people crossing a narrow view can pull the maps' match).
STILL_FIT = (0.05, 1.2)


def _parabola(left: float, peak: float, right: float) -> float:
    """Offset (-0.5 ... 0.5) of the maximum of the parabola through three samples."""
    curvature = left - 2.0 * peak + right
    if curvature >= 0.0:
        return 0.0
    return float(np.clip(0.5 * (left - right) / curvature, -0.5, 0.5))


def match_maps(previous: np.ndarray, current: np.ndarray) -> np.ndarray | None:
    """The motion ``(dx, dy, dyaw)`` (cells, radians; float64) that best moves ``previous``
    onto ``current`` (both ``(H, W)`` bool), or ``None`` where no motion explains ``current``
    clearly better than none (see the module docstring)."""
    previous, current = np.asarray(previous, bool), np.asarray(current, bool)
    if previous.shape != current.shape or previous.ndim != 2:
        raise ValueError(f"maps must be two (H, W) grids, got {previous.shape} and {current.shape}")
    found = correlate(previous, current)
    if found is None or found.score < max(found.still * MIN_GAIN, found.still + _MIN_EXTRA_CELLS):
        return None
    up, down, left, right, before, after = found.neighbours
    da = _parabola(up, found.score, down)
    db = _parabola(left, found.score, right)
    yaw = float(YAWS[found.k])
    if before is not None and after is not None:
        yaw += float(YAWS[1] - YAWS[0]) * _parabola(before, found.score, after)
    # Index shift (a, b) down/right = (x, y) = (a, b) cells in the metric frame (x up, y left,
    # both against the indices, and the match samples at q - shift): u = (a, b); d = R u.
    ux, uy = found.a + da, found.b + db
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([c * ux - s * uy, s * ux + c * uy, yaw])


@dataclass
class _Returns:
    """A frame's returns, and their :class:`~lidarflow.motion.icp.Reference`, made the first
    time it is needed (a frame kept after a pose is often never aligned to)."""

    points: np.ndarray

    @cached_property
    def reference(self) -> Reference:
        return Reference(self.points)


class ScanOdometry:
    """The motion since the previous frame on a stream: ``update(occupancy, points)`` gives it
    in cells and radians (``None`` for the first frame, or where none was found).

    With the maps alone it is :func:`match_maps`. Given each frame's returns
    (:func:`~lidarflow.motion.icp.scan_points`), the match is refined on them
    (:func:`~lidarflow.motion.icp.align`, from the maps' match or else the last motion) and
    reported only where it lays the returns clearly better than standing still
    (:data:`STILL_FIT`): onto the previous frame's where the maps show a motion; else onto
    those :data:`STILL_WINDOW` frames back, once they have moved :data:`MIN_TRAVEL` cells.
    """

    def __init__(self, res: float = 0.1) -> None:
        self.res = res
        self._previous: np.ndarray | None = None
        self._returns: deque[_Returns] = deque(maxlen=STILL_WINDOW + 1)
        self._steps: deque[np.ndarray] = deque(maxlen=STILL_WINDOW)  # metres, between returns

    def reset(self) -> None:
        self._previous = None
        self._returns.clear()
        self._steps.clear()

    def observe(self, occupancy: np.ndarray, points: np.ndarray | None = None) -> None:
        """Take this frame as the one the next update matches against, without matching it
        (a frame whose motion came from elsewhere, such as a pose)."""
        self._previous = np.asarray(occupancy, dtype=bool)
        self._restart(points)

    def update(self, occupancy: np.ndarray, points: np.ndarray | None = None) -> np.ndarray | None:
        current = np.asarray(occupancy, dtype=bool)
        previous, self._previous = self._previous, current
        if previous is None or previous.shape != current.shape:
            self._restart(points)
            return None
        coarse = match_maps(previous, current)
        if points is None or not self._returns:
            self._restart(points)
            return coarse
        guess = self._steps[-1] if self._steps else np.zeros(3)
        if coarse is not None:
            guess = np.array([coarse[0] * self.res, coarse[1] * self.res, coarse[2]])
        previous_points = self._returns[-1].reference
        fine = align(points, previous_points, guess) or align(points, previous_points)
        if fine is None:
            self._restart(points)
            return coarse
        self._returns.append(_Returns(points))
        self._steps.append(fine.motion)
        if coarse is not None:
            moved = _fits_better_than_still(points, previous_points, fine)
        else:
            moved = len(self._returns) > STILL_WINDOW and self._travelled()
        if not moved:
            return None
        return np.array([fine.motion[0] / self.res, fine.motion[1] / self.res, fine.motion[2]])

    def _restart(self, points: np.ndarray | None) -> None:
        self._returns.clear()
        self._steps.clear()
        if points is not None:
            self._returns.append(_Returns(points))

    def _travelled(self) -> bool:
        """Whether the returns have moved by :data:`MIN_TRAVEL` cells over the window, and
        standing still would explain them clearly worse (see :data:`STILL_FIT`)."""
        latest, oldest = self._returns[-1], self._returns[0]
        direct = align(latest.points, oldest.reference, compose(self._steps))
        if direct is None:
            return False
        dx, dy, dyaw = direct.motion
        if float(np.hypot(dx, dy)) / self.res + abs(float(dyaw)) * TURN_REACH < MIN_TRAVEL:
            return False
        return _fits_better_than_still(latest.points, oldest.reference, direct)


def _fits_better_than_still(current: np.ndarray, earlier: Reference, found: Alignment) -> bool:
    """Whether ``found`` lays ``current`` onto ``earlier`` clearly better than no motion does
    (:data:`STILL_FIT`)."""
    share, rms = fit(current, earlier, np.zeros(3))
    fewer, wider = STILL_FIT
    return share < found.inliers - fewer or rms > found.rms * wider


def checked_motion(
    check: OdometryCheck,
    scans: ScanOdometry | None,
    occupancy: np.ndarray,
    motion: np.ndarray | None,
    from_pose: bool,
    points: np.ndarray | None = None,
    pace: float | None = None,
) -> tuple[np.ndarray | None, bool]:
    """The motion a model that may run without poses compensates this frame by, and whether
    ``check`` trusts ``motion``.

    A motion from poses is used while ``check`` trusts it (``scans`` only keeps the frame,
    :meth:`ScanOdometry.observe`); where it does not, or judges the step a jump, the scans' own
    (``scans`` fed this map and ``points``), else, for a jump, ``check``'s stand-in. A motion
    from the scans (``from_pose`` false) is only checked: ``None`` where distrusted, the
    stand-in where judged a jump. ``pace``: the typical step over this one after a long step
    (:func:`lidarflow.motion.pacing.paces_after_long_steps`)."""
    span = 1.0 if not pace else 1.0 / pace
    trusted = check.update(occupancy, motion, span)
    stand_in = check.stand_in(span) if check.jumped and check.trusted else None
    if not from_pose:
        return (motion if trusted else stand_in), trusted
    if trusted:
        if scans is not None:
            scans.observe(occupancy, points)
        return motion, trusted
    found = None if scans is None else scans.update(occupancy, points)
    return (stand_in if found is None else found), trusted


def compose(steps: Iterable[np.ndarray]) -> np.ndarray:
    """The motion ``(dx, dy, dyaw)`` of consecutive motions ``steps`` (oldest first) taken in
    turn: the last pose in the first one's frame (float64, their units)."""
    x = y = yaw = 0.0
    for dx, dy, dyaw in steps:
        c, s = np.cos(yaw), np.sin(yaw)
        x, y, yaw = x + c * dx - s * dy, y + s * dx + c * dy, yaw + dyaw
    return np.array([x, y, yaw])


def scan_motions(
    occupancy: np.ndarray | Sequence[np.ndarray],
    points: Sequence[np.ndarray] | None = None,
    res: float = 0.1,
) -> np.ndarray:
    """Per-frame motions ``(N, 3)`` (cells, radians; float32) of a recording's maps ``(N, H, W)``
    on a grid of ``res`` metres, refined on each frame's returns ``points`` where given (see
    :class:`ScanOdometry`), NaN where none was found (frame 0 too)."""
    if points is not None and len(points) != len(occupancy):
        raise ValueError(f"{len(points)} frames of returns for {len(occupancy)} maps")
    odometry = ScanOdometry(res)
    out = np.full((len(occupancy), 3), np.nan, np.float32)
    for t, frame in enumerate(occupancy):
        motion = odometry.update(frame, None if points is None else points[t])
        if motion is not None:
            out[t] = motion
    return out
