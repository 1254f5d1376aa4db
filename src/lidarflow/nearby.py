"""Cells near other cells: the metrics' tolerance, a Euclidean disc of cells around a cell
(:data:`TOLERANCE`), the dilation by it (:func:`near`) and counts through it
(:func:`near_counts`)."""

from __future__ import annotations

import functools

import numpy as np

__all__ = ["TOLERANCE", "disc", "near", "near_counts"]


#: Cells within which a prediction counts as near a true cell (Euclidean): 0.2 m by default.
TOLERANCE = 2


@functools.lru_cache(maxsize=8)
def disc(radius: int) -> np.ndarray:
    """The offsets ``(N, 2)`` int ``(row, col)`` within a Euclidean ``radius`` of a cell, the
    cell's own ``(0, 0)`` among them, rows first; read-only.

    >>> disc(1).tolist()
    [[-1, 0], [0, -1], [0, 0], [0, 1], [1, 0]]
    """
    offsets = np.arange(-radius, radius + 1)
    dr, dc = (a.ravel() for a in np.meshgrid(offsets, offsets, indexing="ij"))
    inside = dr * dr + dc * dc <= radius * radius
    offsets = np.stack([dr[inside], dc[inside]], axis=1)
    offsets.setflags(write=False)
    return offsets


def near_counts(masks: np.ndarray, cells: np.ndarray, radius: int = TOLERANCE) -> np.ndarray:
    """Per map of ``masks`` ``(C, H, W)`` bool, how many of the ``cells`` ``(H, W)`` bool have
    a ``True`` cell of it within ``radius``: ``(C,)`` int, ``count_nonzero(cells &
    near(masks))`` per map, at a cost that grows with the cells counted, not the grid."""
    h, w = cells.shape
    rows, cols = np.nonzero(cells)
    if not rows.size:
        return np.zeros(len(masks), np.intp)
    offsets = disc(radius)
    r, c = rows[:, None] + offsets[:, 0], cols[:, None] + offsets[:, 1]  # (cells, disc)
    inside = (r >= 0) & (r < h) & (c >= 0) & (c < w)
    hits = masks.reshape(len(masks), -1)[:, np.where(inside, r * w + c, 0)] & inside
    return np.count_nonzero(hits.any(axis=2), axis=1)


def near(mask: np.ndarray, radius: int = TOLERANCE) -> np.ndarray:
    """The cells of ``(..., H, W)`` bool ``mask`` dilated by a Euclidean disc of ``radius``
    cells: ``True`` where a ``True`` cell of ``mask`` lies within ``radius`` cells.

    >>> near(np.eye(1, 5, 2, dtype=bool), 1).astype(int)
    array([[0, 1, 1, 1, 0]])
    """
    mask = np.asarray(mask, bool)
    if mask.ndim < 2:
        raise ValueError(f"mask must be (..., H, W), got {mask.shape}")
    if radius < 0:
        raise ValueError(f"radius must be >= 0, got {radius}")
    h, w = mask.shape[-2:]
    out = mask.copy()
    for dr, dc in disc(radius).tolist():
        if (dr, dc) == (0, 0) or abs(dr) >= h or abs(dc) >= w:
            continue
        # out[r, c] |= mask[r + dr, c + dc] where that cell exists
        out[..., max(0, -dr) : h - max(0, dr), max(0, -dc) : w - max(0, dc)] |= mask[
            ..., max(0, dr) : h - max(0, -dr), max(0, dc) : w - max(0, -dc)
        ]
    return out
