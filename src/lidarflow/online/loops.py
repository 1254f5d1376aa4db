"""Compiled loops of the online combination (:mod:`lidarflow.compiled`): the leader's counts
of each candidate's decided map, the cells some expert finds possibly occupied, and the
stacking's choice of thresholds.

Each does its NumPy reference's arithmetic in its order (``leader.score_counts``,
``stacking.HorizonStacking._split``, ``stacking.best_thresholds``), so the results are
bit-identical; the callers take a loop only where :func:`lidarflow.compiled.ready` says so.
The loops share this module: numba's disk cache sees a change to a loop's own file only.
"""

from __future__ import annotations

import numpy as np

from lidarflow.compiled import kernel

__all__ = [
    "active_loop",
    "decision_counts_loop",
    "quantised_loop",
    "score_counts_loop",
    "thresholds_loop",
]


# A cell's code in score_counts_loop: the bits of what it is.
_RARE, _CHANGED, _OCCUPIED, _REGION, _NEAR_TRUE = 1, 2, 4, 8, 16


@kernel
def score_counts_loop(
    decided: np.ndarray,
    rare: np.ndarray,
    region: np.ndarray,
    occupied: np.ndarray,
    before: np.ndarray,
    radius: int,
) -> tuple[np.ndarray, np.ndarray]:
    """``leader.score_counts`` of ``decided`` ``(C, H, W)`` and the masks ``(H, W)``, all
    bool and C-contiguous, ``radius >= 0``: the counts ``(C, 4, 3)`` (tp, fp, fn per row:
    common, rare, common changed, rare changed) and the tolerant ones ``(C, 4)`` (right,
    wrong, found, missed), float64 holding integers. A cell is near another within the
    Euclidean ``radius``, as :func:`lidarflow.geometry.near` dilates."""
    candidates, h, w = decided.shape
    # each cell coded by what it is; the counts of each code, of all cells and per candidate
    # of those it decides occupied, make every count but the found ones
    code = np.empty((h, w), np.uint8)
    true_rare = []  # the true cells of the tolerant F1, (row, column)
    for r in range(h):
        for c in range(w):
            code[r, c] = (
                rare[r, c] * _RARE
                + (occupied[r, c] != before[r, c]) * _CHANGED
                + occupied[r, c] * _OCCUPIED
                + region[r, c] * _REGION
            )
            if occupied[r, c] and region[r, c]:
                true_rare.append((r, c))
    for r, c in true_rare:  # mark the cells near a true one
        for dr in range(max(-radius, -r), min(radius, h - 1 - r) + 1):
            for dc in range(max(-radius, -c), min(radius, w - 1 - c) + 1):
                if dr * dr + dc * dc <= radius * radius:
                    code[r + dr, c + dc] |= _NEAR_TRUE
    flat = code.reshape(h * w)
    every = np.zeros(32)
    for i in range(h * w):
        every[flat[i]] += 1.0
    true = _rows(every, _OCCUPIED)
    counts = np.zeros((candidates, 4, 3))
    tolerant = np.zeros((candidates, 4))
    for n in range(candidates):
        mine = decided[n]
        mine_flat = mine.reshape(h * w)
        coded = np.zeros(32)
        for i in range(h * w):
            if mine_flat[i]:
                coded[flat[i]] += 1.0
        tp, predicted = _rows(coded, _OCCUPIED), _rows(coded, 0)
        for m in range(4):
            counts[n, m, 0] = tp[m]
            counts[n, m, 1] = predicted[m] - tp[m]
            counts[n, m, 2] = true[m] - tp[m]
        right, guessed = 0.0, 0.0
        for k in range(32):
            if k & _REGION:
                guessed += coded[k]
                if k & _NEAR_TRUE:
                    right += coded[k]
        found = 0.0
        for r, c in true_rare:
            if _any_near(mine, region, r, c, radius):
                found += 1.0
        tolerant[n, 0] = right
        tolerant[n, 1] = guessed - right
        tolerant[n, 2] = found
        tolerant[n, 3] = len(true_rare) - found
    return counts, tolerant


@kernel
def _rows(counts: np.ndarray, having: int) -> np.ndarray:
    """The cells counted by code in ``counts`` ``(32,)`` with the bits ``having``, per row of
    the leader's F1 counts: common, rare, common changed, rare changed."""
    out = np.zeros(4)
    for k in range(32):
        if k & having == having:
            kind = k & _RARE
            out[kind] += counts[k]
            if k & _CHANGED:
                out[2 + kind] += counts[k]
    return out


@kernel
def _any_near(mask: np.ndarray, region: np.ndarray, r: int, c: int, radius: int) -> bool:
    """Whether a cell of ``mask & region`` lies within the Euclidean ``radius`` of ``(r, c)``."""
    h, w = mask.shape
    for dr in range(max(-radius, -r), min(radius, h - 1 - r) + 1):
        for dc in range(max(-radius, -c), min(radius, w - 1 - c) + 1):
            inside = dr * dr + dc * dc <= radius * radius
            if inside and mask[r + dr, c + dc] and region[r + dr, c + dc]:
                return True
    return False


@kernel
def active_loop(flat: np.ndarray, level: float) -> np.ndarray:
    """``stacking.active_cells``: the indices (int64, rising) of the columns of ``flat``
    ``(E, N)`` where some value is above ``level``, compared in ``flat``'s type."""
    experts, cells = flat.shape
    out = np.empty(cells, np.int64)
    found = 0
    for i in range(cells):
        for e in range(experts):
            if flat[e, i] > level:
                out[found] = i
                found += 1
                break
    return out[:found].copy()


@kernel
def quantised_loop(maps: np.ndarray) -> np.ndarray:
    """``combination.quantised``: the float32 maps ``(E, H, W)`` (finite) as uint8
    ``rint(255 clip(p, 0, 1))``, in float32 as NumPy computes it."""
    experts, h, w = maps.shape
    out = np.empty((experts, h, w), np.uint8)
    zero, one, scale = np.float32(0.0), np.float32(1.0), np.float32(255.0)
    for e in range(experts):
        for r in range(h):
            for c in range(w):
                p = min(max(maps[e, r, c], zero), one)
                out[e, r, c] = np.uint8(np.rint(p * scale))
    return out


@kernel
def decision_counts_loop(
    occupied_counts: np.ndarray,
    free_counts: np.ndarray,
    decay: float,
    p: np.ndarray,
    occupied: np.ndarray,
    rare: np.ndarray,
    quiet_p: np.ndarray,
    quiet_counts: np.ndarray,
) -> None:
    """``HorizonStacking._count``'s counting in place: the decayed counts ``(2, bins)`` of
    occupied and free cells per kind and bin of the probability, times ``decay``, plus the
    cells ``p``, ``occupied``, ``rare`` ``(N,)`` and the quiet ones (``quiet_p`` ``(2,)``,
    ``quiet_counts`` ``(2, 2)``: per kind, free then occupied), in the reference's order."""
    bins = occupied_counts.shape[1]
    added = np.zeros((2, 2, bins), np.int64)  # occupied?, kind, bin
    for i in range(len(p)):
        index = min(int(p[i] * bins), bins - 1)
        added[1 if occupied[i] else 0, 1 if rare[i] else 0, index] += 1
    for kind in range(2):
        for index in range(bins):
            occupied_counts[kind, index] *= decay
            occupied_counts[kind, index] += added[1, kind, index]
            free_counts[kind, index] *= decay
            free_counts[kind, index] += added[0, kind, index]
    for kind in range(2):
        index = min(int(quiet_p[kind] * bins), bins - 1)
        free_counts[kind, index] += quiet_counts[kind, 0]
        occupied_counts[kind, index] += quiet_counts[kind, 1]


@kernel
def thresholds_loop(
    occupied: np.ndarray, free: np.ndarray, totals: np.ndarray, rare_weight: float
) -> tuple[int, int]:
    """``stacking.best_thresholds``' choice: the bin indices ``(common, rare)`` whose pair
    scores best (the first of equals, or the first NaN, as ``np.argmax``), from the counts
    ``(2, bins)`` and ``totals`` ``(2,)``, the occupied counts summed as NumPy sums them."""
    bins = occupied.shape[1]
    tp = np.empty((2, bins))
    wrong = np.empty((2, bins))
    for kind in range(2):
        tp_sum, fp_sum = occupied[kind, bins - 1], free[kind, bins - 1]
        for index in range(bins - 1, -1, -1):  # a running sum from the top bin, as cumsum
            if index < bins - 1:
                tp_sum += occupied[kind, index]
                fp_sum += free[kind, index]
            tp[kind, index] = tp_sum
            wrong[kind, index] = fp_sum + (totals[kind] - tp_sum)
    rare_f1 = np.empty(bins)
    for j in range(bins):
        rare_f1[j] = rare_weight * _f1(tp[1, j], wrong[1, j])
    best, chosen_common, chosen_rare = -np.inf, 0, 0
    for i in range(bins):
        for j in range(bins):
            score = _f1(tp[0, i] + tp[1, j], wrong[0, i] + wrong[1, j]) + rare_f1[j]
            if score != score:  # NaN: np.argmax's answer
                return i, j
            if score > best or (i == 0 and j == 0):
                best, chosen_common, chosen_rare = score, i, j
    return chosen_common, chosen_rare


@kernel
def _f1(tp: float, wrong: float) -> float:
    """``stacking.f1_of`` of one count."""
    denominator = 2 * tp + wrong
    return 2 * tp / denominator if denominator > 0 else 0.0
