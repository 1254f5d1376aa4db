"""Compiled loops of :mod:`lidarflow.motion.correlative`: the placements made ready and the
branch and bound search, in one call (:mod:`lidarflow.compiled`).

They do ``_Placements`` and ``correlate``'s arithmetic in its order, the turns' cosines and sines
given, so the turned cells are the reference's to the bit and the scores (integer counts) and
the choices exactly; the caller takes them only where :func:`lidarflow.compiled.ready` says so.
The search's constants come as arguments: numba's disk cache would not see them change.
"""

from __future__ import annotations

import numpy as np

from lidarflow.compiled import kernel

__all__ = ["correlate_loop", "placements_loop"]


@kernel
def placements_loop(
    previous: np.ndarray,
    current: np.ndarray,
    cos: np.ndarray,
    sin: np.ndarray,
    pad: int,
    block: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``_Placements``' arrays: the current map padded by ``pad`` (flat uint8), the same dilated
    over ``block`` shifts down and right, the previous map's occupied cells turned by each turn
    (``(turns, most)`` flat indices, sorted, each once, padded with the dead cell) and their
    counts."""
    h, w = current.shape
    width, rows = w + 2 * pad, h + 4 * pad + 1
    grid = np.zeros((rows, width), np.uint8)
    # dilated: the largest over shifts 0 ... block - 1 down and right, i.e. each occupied cell
    # marks the block up and left of it (a sparse map: a few cells marked, not every cell read)
    dilated = np.zeros((rows, width), np.uint8)
    for i in range(h):
        for j in range(w):
            if current[i, j]:
                grid[pad + i, pad + j] = 1
                for r in range(max(pad + i - block + 1, 0), pad + i + 1):
                    for c in range(max(pad + j - block + 1, 0), pad + j + 1):
                        dilated[r, c] = 1
    dead = (h + 3 * pad) * width + pad
    found_r, found_c = np.nonzero(previous)
    turns = len(cos)
    flat = np.empty((turns, len(found_r)), np.int64)
    counts = np.zeros(turns, np.int64)
    for k in range(turns):
        for n in range(len(found_r)):
            # cells_in_new_frame(r, c, (0, 0, yaw)): geometry.transform_cells' steps, res 1
            x = (h - 0.5 - found_r[n]) * 1.0
            y = (w / 2 - 0.5 - found_c[n]) * 1.0
            x2, y2 = cos[k] * x + sin[k] * y, -sin[k] * x + cos[k] * y
            r, c = np.rint(h - 0.5 - x2 / 1.0), np.rint(w / 2 - 0.5 - y2 / 1.0)
            if r >= 0 and r < h and c >= 0 and c < w:
                flat[k, counts[k]] = (int(r) + pad) * width + int(c) + pad
                counts[k] += 1
    for k in range(turns):  # each turned cell once, in order (a raster of the turned map)
        keys = np.sort(flat[k, : counts[k]])
        kept = 0
        for n in range(len(keys)):
            if n == 0 or keys[n] != keys[n - 1]:
                flat[k, kept] = keys[n]
                kept += 1
        counts[k] = kept
    cells = np.full((turns, max(counts.max(), 1)), dead, np.int64)
    for k in range(turns):
        cells[k, : counts[k]] = flat[k, : counts[k]]
    return grid.ravel(), dilated.ravel(), cells, counts


@kernel
def _score(grid: np.ndarray, cells: np.ndarray, counts: np.ndarray, k: int, offset: int) -> int:
    total = 0
    for n in range(counts[k]):
        total += grid[offset + cells[k, n]]
    return total


@kernel
def _best_in(
    plain: np.ndarray,
    cells: np.ndarray,
    counts: np.ndarray,
    width: int,
    blocks: np.ndarray,
    fine_a: np.ndarray,
    fine_b: np.ndarray,
    rank: np.ndarray,
    span: int,
) -> tuple[int, int, int, int, int]:
    """``_best_of``: the best ``(score, rank, k, a, b)`` in ``blocks`` (the lowest rank among
    the best scores)."""
    top, low, where_k, where_a, where_b = -1, 0, 0, 0, 0
    for block in blocks:
        k, m = block // fine_a.shape[0], block % fine_a.shape[0]
        for j in range(fine_a.shape[1]):
            score = _score(plain, cells, counts, k, fine_a[m, j] * width + fine_b[m, j])
            order = k * span * span + rank[m, j]
            if score > top or (score == top and order < low):
                top, low, where_k, where_a, where_b = score, order, k, fine_a[m, j], fine_b[m, j]
    return top, low, where_k, where_a, where_b


@kernel
def correlate_loop(
    previous: np.ndarray,
    current: np.ndarray,
    cos: np.ndarray,
    sin: np.ndarray,
    corners_a: np.ndarray,
    corners_b: np.ndarray,
    fine_a: np.ndarray,
    fine_b: np.ndarray,
    rank: np.ndarray,
    pad: int,
    block: int,
    first_blocks: int,
    span: int,
) -> np.ndarray:
    """``correlate``'s search: ``(k, a, b, score, still, up, down, left, right, before,
    after)`` (int64), the turn's neighbours clamped to the ends of the turns."""
    plain, dilated, cells, counts = placements_loop(previous, current, cos, sin, pad, block)
    width = current.shape[1] + 2 * pad
    turns, corners = len(cos), len(corners_a)
    bounds = np.empty(turns * corners, np.int64)
    for k in range(turns):
        for m in range(corners):
            offset = corners_a[m] * width + corners_b[m]
            bounds[k * corners + m] = _score(dilated, cells, counts, k, offset)
    order = np.argsort(-bounds, kind="mergesort")
    best = _best_in(plain, cells, counts, width, order[:first_blocks], fine_a, fine_b, rank, span)
    # every other block that can still reach the best (ties too, for the reading order)
    rest = order[first_blocks:]
    rest = rest[bounds[rest] >= best[0]]
    if len(rest):
        other = _best_in(plain, cells, counts, width, rest, fine_a, fine_b, rank, span)
        if other[0] > best[0] or (other[0] == best[0] and other[1] < best[1]):
            best = other
    _, _, k, a, b = best
    near_k = (turns // 2, k, k, k, k, max(k - 1, 0), min(k + 1, turns - 1))
    near_a, near_b = (0, a - 1, a + 1, a, a, a, a), (0, b, b, b - 1, b + 1, b, b)
    found = np.empty(11, np.int64)
    found[0], found[1], found[2], found[3] = k, a, b, best[0]
    for n in range(7):
        offset = near_a[n] * width + near_b[n]
        found[4 + n] = _score(plain, cells, counts, near_k[n], offset)
    return found
