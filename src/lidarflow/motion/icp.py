"""The sensor's motion between two scans to a fraction of a cell: point-to-line ICP on returns.

The maps show a motion only once it moves cells; the returns resolve millimetres
(``docs/research/scan_odometry/``). Method (Censi's PL-ICP, simplified): the current returns,
moved by the motion so far, are paired with the nearest previous return around the same bearing,
and the motion is corrected by one damped Gauss-Newton step on their distances along the
previous scan's surface normal. Pairs farther apart than a shrinking gate are left out (people
walking by, unseen parts); the damping keeps what the scene cannot tell at the guess. The
previous scan is made ready once (:class:`Reference`; ``docs/research/scan_speed/``).

Motion convention: ``(dx, dy, dyaw)`` in metres and radians, the current sensor pose in the
previous one's frame: a current return ``p`` lies at ``R p + d`` in the previous frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lidarflow.beams import RETURN, beam_status
from lidarflow.compiled import ready
from lidarflow.data.blocks import FrameBlocks
from lidarflow.data.recording import Recording
from lidarflow.motion.icp_loops import align_loop, fit_loop, reference_loop
from lidarflow.scan import Scan

__all__ = [
    "Alignment",
    "Reference",
    "align",
    "fit",
    "recording_points",
    "scan_points",
    "streamed_points",
]

#: Current returns used at most (evenly thinned); the cost is linear in them.
MAX_POINTS = 400
#: Previous returns searched on each side of a current return's bearing.
WINDOW = 4
#: Pairs farther apart than this (metres) are left out, per iteration; the last repeats.
GATES = (0.5, 0.3, 0.2, 0.12, 0.08)
MAX_ITERATIONS = 15
#: Neighbouring returns further apart than this (metres) give no surface normal.
NORMAL_SPAN = 0.5
#: An alignment counts when at least this share of the current returns (and 20) pair up.
MIN_INLIERS = 0.3
_MIN_PAIRS = 20
_DAMPING = 1e-4


@dataclass(frozen=True)
class Alignment:
    """``motion`` ``(dx, dy, dyaw)`` (metres, radians, float64), the share of the current
    returns paired within the last gate (``inliers``) and their RMS distance from the previous
    scan's surface (``rms``, metres)."""

    motion: np.ndarray
    inliers: float
    rms: float


def scan_points(scan: Scan) -> np.ndarray:
    """The returns of ``scan`` as ``(N, 2)`` float64 ``(x, y)`` metres in the sensor frame
    (REP 103), ordered by bearing; ``no return`` and unknown beams are left out."""
    g = scan.geometry
    # classified in the stored dtype, as the rasterizer does (a reading at range_max is none)
    keep = beam_status(np.asarray(scan.ranges), g.range_min, g.range_max) == RETURN
    ranges = np.asarray(scan.ranges, dtype=np.float64)
    angles = g.angles[keep]
    order = np.argsort(np.mod(angles, 2 * np.pi), kind="stable")
    r, a = ranges[keep][order], angles[order]
    return np.stack([r * np.cos(a), r * np.sin(a)], axis=1)


def recording_points(recording: Recording) -> list[np.ndarray]:
    """:func:`scan_points` of every frame of ``recording``."""
    return [scan_points(scan) for scan in recording]


def streamed_points(recording: Recording) -> FrameBlocks:
    """:func:`recording_points`, a block of frames at a time (:mod:`lidarflow.data.blocks`)."""
    return FrameBlocks(lambda a, b: recording_points(recording.slice(a, b)), len(recording))


def _normals(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals of the surface through each return and its two bearing neighbours, and
    where there is one (both neighbours within :data:`NORMAL_SPAN` of each other)."""
    before, after = np.roll(points, 1, axis=0), np.roll(points, -1, axis=0)
    tangent = after - before
    length = np.hypot(tangent[:, 0], tangent[:, 1])
    valid = (length > 1e-9) & (length < NORMAL_SPAN)
    normal = np.stack([-tangent[:, 1], tangent[:, 0]], axis=1) / np.maximum(length, 1e-9)[:, None]
    if len(points) > 2:  # a partial field of view does not wrap around
        span = np.hypot(*(points[0] - points[-1]))
        if span >= NORMAL_SPAN:
            valid[[0, -1]] = False
    return normal, valid


def _rotation(yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s], [s, c]])


class Reference:
    """A scan's returns ready to be paired with (the previous scan of an alignment): ordered
    by bearing, with their surface normals and each one's window of bearing neighbours; built
    once, as a stream aligns to the same scan several times."""

    def __init__(self, points: np.ndarray) -> None:
        points = _checked(points)
        # one compiled pass: below, NumPy's dozen small calls cost more than their work
        if len(points) and ready(reference_loop, points, WINDOW, NORMAL_SPAN):
            (self.points, self.bearings, self.normal, self.has_normal, self._window_x,
             self._window_y) = reference_loop(points, WINDOW, NORMAL_SPAN)  # fmt: skip
            return
        bearings = np.mod(np.arctan2(points[:, 1], points[:, 0]), 2 * np.pi)
        order = np.argsort(bearings, kind="stable")  # scan_points' order, whatever was given
        self.points, self.bearings = points[order], bearings[order]
        self.normal, self.has_normal = _normals(self.points)
        n = len(self.points)
        # row i: the returns i - WINDOW ... i + WINDOW - 1 around the bearing circle, the
        # candidates of a point whose bearing sorts in at i (one gather per pairing)
        around = np.mod(np.arange(-WINDOW, n + WINDOW), max(n, 1))
        windows = np.lib.stride_tricks.sliding_window_view(
            self.points[around] if n else np.zeros((2 * WINDOW, 2)), 2 * WINDOW, axis=0
        )[: n + 1]
        self._window_x, self._window_y = (np.ascontiguousarray(windows[:, i]) for i in (0, 1))

    @property
    def _arrays(self) -> tuple[np.ndarray, ...]:
        """What the compiled loops pair with, in their order (:func:`reference_loop`'s)."""
        return (self.points, self.bearings, self.normal, self.has_normal, self._window_x,
                self._window_y)  # fmt: skip

    def __len__(self) -> int:
        return len(self.points)

    def pair(
        self, source: np.ndarray, motion: np.ndarray, gate: float
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``source`` moved by ``motion``, the index of each one's nearest return around its
        bearing, and whether that pair counts (within ``gate`` metres, on a surface)."""
        # Small arrays: the cost is numpy's per-call overhead, so as few calls as will do.
        moved = source @ _rotation(float(motion[2])).T + motion[:2]
        x, y = moved[:, 0], moved[:, 1]
        at = np.searchsorted(self.bearings, np.mod(np.arctan2(y, x), 2 * np.pi))
        gap = np.take(self._window_x, at, axis=0)  # take: half the time of fancy indexing
        gap -= x[:, None]
        np.square(gap, out=gap)
        across = np.take(self._window_y, at, axis=0)
        across -= y[:, None]
        gap += np.square(across, out=across)
        nearest = gap.argmin(axis=1)
        closest = np.take(gap, np.arange(0, gap.size, 2 * WINDOW) + nearest)
        best = at + nearest
        best -= WINDOW
        best %= len(self.points)
        inliers = closest < gate * gate
        inliers &= self.has_normal[best]
        return moved, best, inliers

    def distances(self, moved: np.ndarray, best: np.ndarray) -> np.ndarray:
        """Signed distances of ``moved`` from the surface through their paired returns."""
        return ((moved - self.points[best]) * self.normal[best]).sum(axis=1)


def _checked(points: np.ndarray) -> np.ndarray:
    points = np.asarray(points, np.float64)
    if points.ndim != 2 or points.shape[-1] != 2:
        raise ValueError(f"points must be (N, 2), got {points.shape}")
    return points


def _source(current: np.ndarray) -> np.ndarray:
    """``current``'s returns, checked, evenly thinned to :data:`MAX_POINTS` at most."""
    current = _checked(current)
    return current[:: int(np.ceil(len(current) / MAX_POINTS)) or 1]


def _reference(previous: np.ndarray | Reference) -> Reference:
    return previous if isinstance(previous, Reference) else Reference(previous)


def align(
    current: np.ndarray, previous: np.ndarray | Reference, initial: np.ndarray | None = None
) -> Alignment | None:
    """The motion that lays ``current``'s returns onto ``previous``'s (both from
    :func:`scan_points`, ``previous`` also as a :class:`Reference`), starting from ``initial``
    (default none), or ``None`` where too few returns pair up (:data:`MIN_INLIERS`)."""
    source, target = _source(current), _reference(previous)
    if len(source) < _MIN_PAIRS or len(target) < 3:
        return None
    motion = np.zeros(3) if initial is None else np.asarray(initial, np.float64).reshape(3).copy()
    args = (source, *target._arrays, motion, np.array(GATES), MAX_ITERATIONS, _MIN_PAIRS,
            _DAMPING)  # fmt: skip
    if ready(align_loop, *args):
        if not align_loop(*args):
            return None
        return _alignment(target, source, motion)
    for iteration in range(MAX_ITERATIONS):
        moved, best, inliers = target.pair(source, motion, GATES[min(iteration, len(GATES) - 1)])
        if inliers.sum() < _MIN_PAIRS:
            return None
        step = _gauss_newton_step(target, moved[inliers], best[inliers], motion)
        motion += step
        settled = math.hypot(step[0], step[1]) < 1e-5 and abs(step[2]) < 1e-6
        if settled and iteration >= len(GATES) - 1:
            break
    return _alignment(target, source, motion)


def _alignment(target: Reference, source: np.ndarray, motion: np.ndarray) -> Alignment | None:
    share, rms = _fit(target, source, motion)
    if share < MIN_INLIERS:
        return None
    return Alignment(motion=motion, inliers=share, rms=rms)


def _gauss_newton_step(
    target: Reference, p: np.ndarray, paired: np.ndarray, motion: np.ndarray
) -> list[float]:
    """The damped Gauss-Newton step on the distances of the moved returns ``p`` from the
    surface through their ``paired`` returns."""
    n = target.normal[paired]
    # columns: d distance / d (dx, dy, dyaw), then the distance; one product gives J^T J and
    # J^T r. d(R s)/d(yaw) is R s turned by 90 degrees, s = p - d.
    system = np.empty((len(p), 4))
    system[:, :2] = n
    lever = p - motion[:2]
    np.subtract(n[:, 1] * lever[:, 0], n[:, 0] * lever[:, 1], out=system[:, 2])
    offset = (p - target.points[paired]) * n
    np.add(offset[:, 0], offset[:, 1], out=system[:, 3])
    (a, b, c, g0), (_, d, e, g1), (_, _, f, g2), _ = (system.T @ system).tolist()
    damping = _DAMPING * (a + d + f) + 1e-12
    a, d, f = a + damping, d + damping, f + damping
    # the symmetric 3 x 3 system [[a, b, c], [b, d, e], [c, e, f]] x = -g by Cramer's rule
    m0, m1, m2 = d * f - e * e, c * e - b * f, b * e - c * d
    det = a * m0 + b * m1 + c * m2
    m4, m5, m8 = a * f - c * c, b * c - a * e, a * d - b * b
    return [
        -(m0 * g0 + m1 * g1 + m2 * g2) / det,
        -(m1 * g0 + m4 * g1 + m5 * g2) / det,
        -(m2 * g0 + m5 * g1 + m8 * g2) / det,
    ]


def fit(
    current: np.ndarray, previous: np.ndarray | Reference, motion: np.ndarray
) -> tuple[float, float]:
    """How well ``motion`` lays ``current``'s returns onto ``previous``'s (as for
    :func:`align`), without fitting: :class:`Alignment`'s ``(inliers, rms)``, ``(0, inf)``
    where none pair."""
    source, target = _source(current), _reference(previous)
    if len(source) == 0 or len(target) < 3:
        return 0.0, float("inf")
    return _fit(target, source, np.asarray(motion, np.float64).reshape(3))


def _fit(target: Reference, source: np.ndarray, motion: np.ndarray) -> tuple[float, float]:
    args = (source, *target._arrays, motion, GATES[-1])
    if ready(fit_loop, *args):
        pairs, total = fit_loop(*args)
        if pairs == 0:
            return 0.0, float("inf")
        return pairs / len(source), math.sqrt(total / pairs)
    moved, best, inliers = target.pair(source, motion, GATES[-1])
    if not inliers.any():
        return 0.0, float("inf")
    distances = target.distances(moved[inliers], best[inliers])
    return float(inliers.mean()), float(np.sqrt(np.mean(distances**2)))
