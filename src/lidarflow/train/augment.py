"""Training windows in which a piece of the static scene moves (``data.static_shift``).

A per-cell head with slow memories (decay 0.995: hundreds of frames) learns from real
recordings that a cell occupied for minutes and seen free for a frame or two is occupied again
next frame: at the edges of walls and furniture that is scan noise, and it is right. When the
structure itself moves (a chair pushed, the sensor nudged on its mount), the same rule keeps
predicting the old cells for hundreds of frames while copying the last map follows at once
(measured on ``positive_4``, ``docs/research/positive_4/``). The development recordings
hold almost no such events, so the head never pays for the rule.

:func:`shift_patch` makes one: from a frame ``k`` of the window on, the maps in a box around an
occupied cell are moved by a cell or two, occupancy and visibility together, and stay moved.
The head's memories at the window's start are streamed from the unaltered recording
(``data.memories_from_stream``), so the window starts with a long, confident history of the old
cells, as a real moved structure would.
"""

from __future__ import annotations

import numpy as np

__all__ = ["shift_patch"]


def shift_patch(
    window: np.ndarray,
    rng: np.random.Generator,
    first: int,
    max_half: int = 6,
    max_step: int = 2,
) -> np.ndarray:
    """A copy of boolean ``window`` ``(T, 2, H, W)`` in which, from a frame ``k`` in
    ``[first, T - 2]`` on, the box of half-size 1..``max_half`` cells around a cell occupied at
    ``k`` shows what lay ``(dy, dx)`` (each in ``-max_step..max_step``, not both 0) from it:
    its content moved by ``(-dy, -dx)``. ``window`` itself unchanged when no frame in range
    has an occupied cell away from the border."""
    t, _, h, w = window.shape
    out = window.copy()
    k = int(rng.integers(first, t - 1)) if first < t - 1 else t - 2
    if k < 0:
        return out
    margin = max_half + max_step
    ys, xs = np.nonzero(window[k, 0, margin : h - margin, margin : w - margin])
    if len(ys) == 0:
        return out
    pick = int(rng.integers(len(ys)))
    cy, cx = int(ys[pick]) + margin, int(xs[pick]) + margin
    half = int(rng.integers(1, max_half + 1))
    dy, dx = 0, 0
    while dy == 0 and dx == 0:
        dy, dx = (int(v) for v in rng.integers(-max_step, max_step + 1, size=2))
    y0, y1, x0, x1 = cy - half, cy + half + 1, cx - half, cx + half + 1
    out[k:, :, y0:y1, x0:x1] = window[k:, :, y0 + dy : y1 + dy, x0 + dx : x1 + dx]
    return out
