"""The tracker's per-frame split of the occupied cells (:class:`lidarflow.tracking.Tracker`'s
steps 1-2): the running background rate updated where visible, and the occupied cells sorted
into moving (foreground), held and static ones. Compiled where :mod:`lidarflow.compiled` is
available (one pass over the map), else in NumPy (the reference, to the bit)."""

from __future__ import annotations

import numpy as np

from lidarflow.compiled import kernel, ready
from lidarflow.tracking.clusters import foreground

__all__ = ["split"]


def split(
    occupied: np.ndarray,
    visible: np.ndarray,
    background: np.ndarray,
    seen: np.ndarray,
    alpha: float,
    threshold: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One frame of the background: ``(moving, held, static, rate)``, three ``(H, W)`` bool and
    the new ``(H, W)`` float64 rate.

    ``occupied``, ``visible`` ``(H, W)`` bool (``visible`` covers ``occupied``); ``background``
    ``(H, W)`` float64 and ``seen`` ``(H, W)`` bool, the tracker's own, updated in place: a cell
    visible for the first time takes its occupancy as its rate and is marked seen. Then
    ``moving`` = :func:`foreground` of that rate at ``threshold``; ``held``: occupied, not
    moving, yet its own rate under ``threshold``; ``static``: occupied and not moving; ``rate``:
    ``(1 - alpha) * rate + alpha * occupied`` where visible, the rate elsewhere (a new array).
    """
    kinds = (occupied.dtype, visible.dtype, background.dtype, seen.dtype)
    h, w = occupied.shape
    moving, held, static = (np.empty((h, w), bool) for _ in range(3))
    rate = np.empty((h, w), np.float64)
    keep = 1 - alpha  # as the reference forms it
    args = (occupied, visible, background, seen, keep, alpha, threshold, moving, held, static, rate)
    # (other types: NumPy's own promotions, which the loop does not copy)
    if kinds != (np.bool_, np.bool_, np.float64, np.bool_) or not ready(_split_loop, *args):
        return _split_numpy(occupied, visible, background, seen, alpha, threshold)
    _split_loop(*args)
    return moving, held, static, rate


def _split_numpy(
    occupied: np.ndarray,
    visible: np.ndarray,
    background: np.ndarray,
    seen: np.ndarray,
    alpha: float,
    threshold: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`split` in NumPy (the reference)."""
    new = visible & ~seen
    background[new] = occupied[new]
    seen |= visible
    moving = foreground(occupied, background, threshold)
    # rare here but beside a wall (the 3 x 3 neighbourhood): held, not tracked
    held = occupied & ~moving & (background < threshold)
    rate = (1 - alpha) * background + alpha * occupied
    return moving, held, occupied & ~moving, np.where(visible, rate, background)


@kernel
def _split_loop(
    occupied: np.ndarray,
    visible: np.ndarray,
    background: np.ndarray,
    seen: np.ndarray,
    keep: float,
    alpha: float,
    threshold: float,
    moving: np.ndarray,
    held: np.ndarray,
    static: np.ndarray,
    rate: np.ndarray,
) -> None:
    """:func:`_split_numpy` in one pass: row ``r`` takes its newly seen cells, then row
    ``r - 1``, whose 3 x 3 neighbourhood is then final, is split and its rate written."""
    h, w = occupied.shape
    for r in range(h + 1):
        if r < h:
            for c in range(w):
                if visible[r, c] and not seen[r, c]:
                    background[r, c] = 1.0 if occupied[r, c] else 0.0
                    seen[r, c] = True
        q = r - 1
        if q < 0:
            continue
        for c in range(w):
            b = background[q, c]
            go = False
            if occupied[q, c]:
                go = _near_under(background, q, c, threshold)
            moving[q, c] = go
            held[q, c] = occupied[q, c] and not go and b < threshold
            static[q, c] = occupied[q, c] and not go
            if visible[q, c]:
                # the reference's sum: (1 - alpha) * rate + alpha * (0.0 or 1.0)
                rate[q, c] = keep * b + alpha * (1.0 if occupied[q, c] else 0.0)
            else:
                rate[q, c] = b


@kernel
def _near_under(background: np.ndarray, q: int, c: int, threshold: float) -> bool:
    """Whether the largest rate over the 3 x 3 neighbourhood of ``(q, c)`` (zero beyond the
    map, as :func:`foreground`'s padding) is under ``threshold``; a NaN there makes it not (as
    NumPy's maximum spreads it and the comparison fails). The maximum is exact in any order."""
    h, w = background.shape
    top = -np.inf
    for rr in range(q - 1, q + 2):
        for cc in range(c - 1, c + 2):
            v = 0.0
            if 0 <= rr < h and 0 <= cc < w:
                v = background[rr, cc]
            if v != v:
                return False
            if v > top:
                top = v
    return top < threshold
