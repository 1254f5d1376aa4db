"""Compiled loops of :mod:`lidarflow.motion.icp`: the ICP iterations, making a previous scan
ready to pair with, and judging a motion's fit (:mod:`lidarflow.compiled`).

Each does its NumPy reference's arithmetic (``icp.align``'s iterations, ``Reference.__init__``,
``icp._fit``); the callers take it only where :func:`lidarflow.compiled.ready` says so.
:func:`reference_loop` is bit-identical to its reference. The other two move the returns by
scalar products where the reference multiplies matrices (the BLAS may fuse them) and sum in turn
where NumPy sums pairwise: a moved return differs in the last bits of its metres (1e-15 m), and
so a motion and an ``rms`` (well within 1e-12 m; the tests hold them to that); the pairs are the
reference's but where a distance lies within those bits of the gate. Each return's bearing place
is looked for from the one before (the same place as ``np.searchsorted``'s). The loops share
this module: numba's disk cache sees a change to a loop's own file only.
"""

from __future__ import annotations

import math

import numpy as np

from lidarflow.compiled import kernel

__all__ = ["align_loop", "fit_loop", "reference_loop"]


@kernel
def _bearing(x: float, y: float) -> float:
    """``atan2(y, x) % 2 pi`` without the division a float ``%`` takes (the same value; -0.0
    for +0.0, which compares equal)."""
    angle = math.atan2(y, x)
    return angle + 2 * math.pi if angle < 0.0 else angle


@kernel
def _slot(bearings: np.ndarray, angle: float, hint: int) -> int:
    """``np.searchsorted(bearings, angle)``, looked for from ``hint`` first: returns in bearing
    order land a step or two after the one before."""
    n, at = len(bearings), min(max(hint, 0), len(bearings))
    for _ in range(8):
        if at < n and bearings[at] < angle:
            at += 1
        elif at > 0 and bearings[at - 1] >= angle:
            at -= 1
        else:
            return at
    return np.searchsorted(bearings, angle)


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
def _paired(
    px: float,
    py: float,
    cos: float,
    sin: float,
    motion: np.ndarray,
    bearings: np.ndarray,
    window_x: np.ndarray,
    window_y: np.ndarray,
    at: int,
) -> tuple[float, float, int, int, float]:
    """One return ``(px, py)`` moved by ``motion`` (``cos``, ``sin`` of its turn) and paired as
    ``Reference.pair`` pairs it: ``(x, y)``, its place among the bearings (searched from the
    previous return's, ``at``), the index of its nearest return and their squared distance."""
    x = px * cos - py * sin + motion[0]
    y = px * sin + py * cos + motion[1]
    at = _slot(bearings, _bearing(x, y), at)
    nearest, closest = 0, np.inf
    window = window_x.shape[1]
    for k in range(window):
        gap = (window_x[at, k] - x) ** 2 + (window_y[at, k] - y) ** 2
        if gap < closest:
            nearest, closest = k, gap
    return x, y, at, (at + nearest - window // 2) % len(bearings), closest


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
    cos, sin = math.cos(motion[2]), math.sin(motion[2])
    pairs, total, at = 0, 0.0, 0
    for i in range(len(source)):
        x, y, at, best, closest = _paired(source[i, 0], source[i, 1], cos, sin, motion,
                                          bearings, window_x, window_y, at)  # fmt: skip
        if closest >= gate * gate or not has_normal[best]:
            continue
        pairs += 1
        distance = (x - points[best, 0]) * normal[best, 0] + (y - points[best, 1]) * normal[best, 1]
        total += distance * distance
    return pairs, total


@kernel
def align_loop(
    source: np.ndarray,
    points: np.ndarray,
    bearings: np.ndarray,
    normal: np.ndarray,
    has_normal: np.ndarray,
    window_x: np.ndarray,
    window_y: np.ndarray,
    motion: np.ndarray,
    gates: np.ndarray,
    iterations: int,
    min_pairs: int,
    damping_share: float,
) -> bool:
    """``icp.align``'s iterations in one pass per iteration, ``motion`` updated in place;
    False where too few returns pair up. The same pairing and step as ``Reference.pair`` and
    ``icp._gauss_newton_step``, summed in another order (last bits may differ)."""
    for iteration in range(iterations):
        gate = gates[min(iteration, len(gates) - 1)]
        cos, sin = math.cos(motion[2]), math.sin(motion[2])
        a = b = c = d = e = f = g0 = g1 = g2 = 0.0
        pairs, at = 0, 0
        for i in range(len(source)):
            x, y, at, best, closest = _paired(source[i, 0], source[i, 1], cos, sin, motion,
                                              bearings, window_x, window_y, at)  # fmt: skip
            if closest >= gate * gate or not has_normal[best]:
                continue
            pairs += 1
            n0, n1 = normal[best, 0], normal[best, 1]
            lever = n1 * (x - motion[0]) - n0 * (y - motion[1])
            r = (x - points[best, 0]) * n0 + (y - points[best, 1]) * n1
            a += n0 * n0
            b += n0 * n1
            c += n0 * lever
            d += n1 * n1
            e += n1 * lever
            f += lever * lever
            g0 += n0 * r
            g1 += n1 * r
            g2 += lever * r
        if pairs < min_pairs:
            return False
        damping = damping_share * (a + d + f) + 1e-12
        a, d, f = a + damping, d + damping, f + damping
        m0, m1, m2 = d * f - e * e, c * e - b * f, b * e - c * d
        det = a * m0 + b * m1 + c * m2
        m4, m5, m8 = a * f - c * c, b * c - a * e, a * d - b * b
        s0 = -(m0 * g0 + m1 * g1 + m2 * g2) / det
        s1 = -(m1 * g0 + m4 * g1 + m5 * g2) / det
        s2 = -(m2 * g0 + m5 * g1 + m8 * g2) / det
        motion[0] += s0
        motion[1] += s1
        motion[2] += s2
        if math.hypot(s0, s1) < 1e-5 and abs(s2) < 1e-6 and iteration >= len(gates) - 1:
            break
    return True
