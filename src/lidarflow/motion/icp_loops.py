"""Compiled loops of :mod:`lidarflow.motion.icp` beside the ICP iterations: making a previous
scan ready to pair with, and judging a motion's fit (:mod:`lidarflow.compiled`).

Each does its NumPy reference's arithmetic (``Reference.__init__``, ``icp._fit``); the callers
take it only where :func:`lidarflow.compiled.ready` says so. :func:`reference_loop` is
bit-identical to its reference. :func:`fit_loop` moves the returns by scalar products where the
reference multiplies matrices (the BLAS may fuse them) and sums the squared distances in turn
where NumPy sums them pairwise: a moved return differs in the last bits of its metres (1e-15 m),
and so the ``rms`` (well within 1e-12 m; the tests hold it to that); the pairs it counts are the
reference's but where a distance lies within those bits of the gate.
"""

from __future__ import annotations

import math

import numpy as np

from lidarflow.compiled import kernel

__all__ = ["fit_loop", "reference_loop"]


@kernel
def reference_loop(
    points: np.ndarray, window: int, normal_span: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``Reference.__init__``'s arrays from ``points`` ``(N, 2)`` float64, N >= 1: the points
    and their bearings in bearing order (stable), their unit normals and whether each has one,
    and the windows ``(N + 1, 2 window)`` of x and of y around each place in that order."""
    n = len(points)
    two_pi = 2 * math.pi
    raw = np.empty(n)
    for i in range(n):
        raw[i] = math.atan2(points[i, 1], points[i, 0]) % two_pi
    order = np.argsort(raw, kind="mergesort")
    sorted_points, bearings = np.empty((n, 2)), np.empty(n)
    for i in range(n):
        sorted_points[i, 0], sorted_points[i, 1] = points[order[i], 0], points[order[i], 1]
        bearings[i] = raw[order[i]]
    normal, has_normal = np.empty((n, 2)), np.empty(n, np.bool_)
    for i in range(n):
        before, after = (i - 1) % n, (i + 1) % n
        t0 = sorted_points[after, 0] - sorted_points[before, 0]
        t1 = sorted_points[after, 1] - sorted_points[before, 1]
        length = math.hypot(t0, t1)
        has_normal[i] = length > 1e-9 and length < normal_span
        scale = max(length, 1e-9)
        normal[i, 0], normal[i, 1] = -t1 / scale, t0 / scale
    if n > 2:  # a partial field of view does not wrap around
        span = math.hypot(
            sorted_points[0, 0] - sorted_points[n - 1, 0],
            sorted_points[0, 1] - sorted_points[n - 1, 1],
        )
        if span >= normal_span:
            has_normal[0] = has_normal[n - 1] = False
    width = 2 * window
    window_x, window_y = np.empty((n + 1, width)), np.empty((n + 1, width))
    for i in range(n + 1):
        for k in range(width):
            j = (i - window + k) % n
            window_x[i, k], window_y[i, k] = sorted_points[j, 0], sorted_points[j, 1]
    return sorted_points, bearings, normal, has_normal, window_x, window_y


@kernel
def fit_loop(
    source: np.ndarray,
    points: np.ndarray,
    bearings: np.ndarray,
    normal: np.ndarray,
    has_normal: np.ndarray,
    window_x: np.ndarray,
    window_y: np.ndarray,
    motion: np.ndarray,
    gate: float,
) -> tuple[int, float]:
    """``source`` moved by ``motion`` and paired as ``Reference.pair`` pairs them: how many
    pairs count (within ``gate``, on a surface) and the sum of their squared signed distances
    from the surface."""
    size, window = len(points), window_x.shape[1]
    cos, sin = math.cos(motion[2]), math.sin(motion[2])
    pairs, total = 0, 0.0
    for i in range(len(source)):
        x = source[i, 0] * cos - source[i, 1] * sin + motion[0]
        y = source[i, 0] * sin + source[i, 1] * cos + motion[1]
        at = np.searchsorted(bearings, math.atan2(y, x) % (2 * math.pi))
        nearest, closest = 0, np.inf
        for k in range(window):
            gap = (window_x[at, k] - x) ** 2 + (window_y[at, k] - y) ** 2
            if gap < closest:
                nearest, closest = k, gap
        best = (at + nearest - window // 2) % size
        if closest >= gate * gate or not has_normal[best]:
            continue
        pairs += 1
        distance = (x - points[best, 0]) * normal[best, 0] + (y - points[best, 1]) * normal[best, 1]
        total += distance * distance
    return pairs, total
