"""Compiled loops of the online combination (:mod:`lidarflow.compiled`): the leader's counts
of each candidate's decided map, the stacking's passes over the grid (the cells some expert
finds possibly occupied, their design, the quiet cells' counts, the decided grid), its decision
counts and choice of thresholds, the quantising of the kept maps, and the leader's choice of
the pair.

Each does its NumPy reference's arithmetic in its order (``leader.score_counts``,
``stacking.active_cells``, ``HorizonStacking._split``, ``stacking._quiet_kinds``,
``HorizonStacking._decided_grid`` and ``_count``, ``stacking.best_thresholds``,
``combination.quantised``, ``Leader._best``), so the results are bit-identical; the
logarithms, exponentials and matrix products stay NumPy's. The callers take a loop only where
:func:`lidarflow.compiled.ready` says so. The loops share this module: numba's disk cache sees
a change to a loop's own file only.
"""

from __future__ import annotations

import numpy as np

from lidarflow.compiled import kernel

__all__ = [
    "active_loop",
    "best_pair_loop",
    "decided_grid_loop",
    "decision_counts_loop",
    "quantised_design_loop",
    "quantised_loop",
    "quiet_kinds_loop",
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
    bool viewed as uint8 (0 or 1) and C-contiguous, ``radius >= 0``: the counts ``(C, 4, 3)``
    (tp, fp, fn per row: common, rare, common changed, rare changed) and the tolerant ones
    ``(C, 4)`` (right, wrong, found, missed), float64 holding integers. A cell is near another
    within the Euclidean ``radius``, as :func:`lidarflow.nearby.near` dilates."""
    candidates, h, w = decided.shape
    # each cell coded by what it is; the counts of each code among the cells a candidate
    # decides occupied make every count but the found ones
    code = np.empty((h, w), np.uint8)
    flat = code.reshape(h * w)
    rare_, region_ = rare.reshape(h * w), region.reshape(h * w)
    occupied_, before_ = occupied.reshape(h * w), before.reshape(h * w)
    for i in range(h * w):
        flat[i] = (
            rare_[i] * _RARE
            + (occupied_[i] ^ before_[i]) * _CHANGED
            + occupied_[i] * _OCCUPIED
            + region_[i] * _REGION
        )
    true = np.zeros(4)
    true_rare = []  # the true cells of the tolerant F1, (row, column)
    for i in range(h * w):
        if occupied_[i]:
            _add_rows(true, flat[i])
            if region_[i]:
                true_rare.append((i // w, i % w))
    for r, c in true_rare:  # mark the cells near a true one
        for dr in range(max(-radius, -r), min(radius, h - 1 - r) + 1):
            for dc in range(max(-radius, -c), min(radius, w - 1 - c) + 1):
                if dr * dr + dc * dc <= radius * radius:
                    code[r + dr, c + dc] |= _NEAR_TRUE
    counts = np.zeros((candidates, 4, 3))
    tolerant = np.zeros((candidates, 4))
    tp, predicted = np.zeros(4), np.zeros(4)
    for n in range(candidates):
        mine = decided[n]
        mine_flat = mine.reshape(h * w)
        tp[:] = 0.0
        predicted[:] = 0.0
        right, guessed = 0.0, 0.0
        for i in range(h * w):
            if mine_flat[i]:
                _add_rows(predicted, flat[i])
                if flat[i] & _OCCUPIED:
                    _add_rows(tp, flat[i])
                if flat[i] & _REGION:
                    guessed += 1.0
                    if flat[i] & _NEAR_TRUE:
                        right += 1.0
        for m in range(4):
            counts[n, m, 0] = tp[m]
            counts[n, m, 1] = predicted[m] - tp[m]
            counts[n, m, 2] = true[m] - tp[m]
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
def _add_rows(rows: np.ndarray, code: int) -> None:
    """Count a cell of ``code`` in ``rows`` ``(4,)``: the leader's rows (common, rare, common
    changed, rare changed) it belongs to."""
    kind = code & _RARE
    rows[kind] += 1.0
    if code & _CHANGED:
        rows[2 + kind] += 1.0


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
    above = np.zeros(cells, np.bool_)
    for e in range(experts):
        for i in range(cells):
            above[i] |= flat[e, i] > level
    return np.flatnonzero(above)


@kernel
def quantised_design_loop(
    flat: np.ndarray, active: np.ndarray, logits: np.ndarray, rare: np.ndarray
) -> np.ndarray:
    """``HorizonStacking._split``'s design ``(2 + 2 E, n)``, in Fortran order as NumPy's is,
    of the ``active`` cells of the quantised maps ``flat`` ``(E, N)`` uint8: 1, rare, the
    experts' ``logits`` (per level, ``(256,)``) and those times rare (``rare`` ``(N,)``
    bool)."""
    experts = flat.shape[0]
    # laid out as NumPy's own design is (cells outer): a matrix product sums in an order
    # that follows the layout
    out = np.empty((len(active), 2 + 2 * experts))
    for n in range(len(active)):
        r = 1.0 if rare[active[n]] else 0.0
        out[n, 0] = 1.0
        out[n, 1] = r
        for e in range(experts):
            logit = logits[flat[e, active[n]]]
            out[n, 2 + e] = logit
            out[n, 2 + experts + e] = logit * r
    return out.T


@kernel
def quiet_kinds_loop(rare: np.ndarray, occupied: np.ndarray, active: np.ndarray) -> np.ndarray:
    """``stacking._quiet_kinds``: the cells ``(2, 2)`` float64 per kind (common, rare) and
    label (free, occupied) of ``rare`` and ``occupied`` ``(N,)`` (bool viewed as uint8) but
    the flat ``active`` ones."""
    both, rare_cells, occupied_cells = 0, 0, 0
    for i in range(len(rare)):
        both += rare[i] & occupied[i]
        rare_cells += rare[i]
        occupied_cells += occupied[i]
    cells = len(rare) - len(active)
    for i in active:
        both -= rare[i] & occupied[i]
        rare_cells -= rare[i]
        occupied_cells -= occupied[i]
    out = np.empty((2, 2))
    out[0, 0] = cells - rare_cells - occupied_cells + both
    out[0, 1] = occupied_cells - both
    out[1, 0] = rare_cells - both
    out[1, 1] = both
    return out


@kernel
def decided_grid_loop(
    active: np.ndarray,
    p: np.ndarray,
    quiet_p: np.ndarray,
    rare: np.ndarray,
    thresholds: np.ndarray,
    decided: float,
) -> np.ndarray:
    """``HorizonStacking._decided_grid``: the flat grid float32 of ``rare`` ``(N,)`` (bool)
    holding the ``active`` cells' ``p`` and elsewhere ``quiet_p`` (not rare, rare), each
    rescaled at the ``thresholds`` (common, rare) of its kind as ``stacking.rescaled`` does
    onto ``decided``."""
    common = _rescaled(quiet_p[0], thresholds[0], decided)
    rare_one = _rescaled(quiet_p[1], thresholds[1], decided)
    out = np.empty(len(rare), np.float32)
    for i in range(len(rare)):
        out[i] = rare_one if rare[i] else common
    for n in range(len(active)):
        kind = 1 if rare[active[n]] else 0
        out[active[n]] = _rescaled(p[n], thresholds[kind], decided)
    return out


@kernel
def _rescaled(p: float, threshold: float, decided: float) -> np.float32:
    """``stacking.rescaled`` of one probability."""
    t = min(max(threshold, 1e-6), 1 - 1e-6)
    low = p * (decided / t)
    high = decided + (p - t) * ((1 - decided) / (1 - t))
    return np.float32(low if p < t else high)


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
    scores = np.empty((bins, bins))
    for i in range(bins):
        for j in range(bins):
            scores[i, j] = _f1(tp[0, i] + tp[1, j], wrong[0, i] + wrong[1, j]) + rare_f1[j]
    return _first_best(scores)


@kernel
def _first_best(scores: np.ndarray) -> tuple[int, int]:
    """The index ``(i, j)`` of ``scores``' largest, as ``np.argmax`` finds it: the first of
    equals, or the first NaN."""
    best, chosen_i, chosen_j = -np.inf, 0, 0
    for i in range(scores.shape[0]):
        for j in range(scores.shape[1]):
            score = scores[i, j]
            if score != score:  # NaN: np.argmax's answer
                return i, j
            if score > best or (i == 0 and j == 0):
                best, chosen_i, chosen_j = score, i, j
    return chosen_i, chosen_j


@kernel
def _f1(tp: float, wrong: float) -> float:
    """``stacking.f1_of`` of one count."""
    denominator = 2 * tp + wrong
    return 2 * tp / denominator if denominator > 0 else 0.0


@kernel
def best_pair_loop(
    f1_counts: np.ndarray,
    tolerant_counts: np.ndarray,
    first: int,
    baselines: np.ndarray,
    loss_weight: float,
) -> tuple[int, int]:
    """``Leader._best``: the pair (common, rare) of the highest score from the decayed
    ``f1_counts`` ``(C, 2, 2, 3)`` and ``tolerant_counts`` ``(C, 4)``, judged against the
    candidates ``baselines`` (int64, copy-last first; empty: the sum of the F1s)."""
    n = f1_counts.shape[0]
    f1 = np.empty((n, n, 2))
    for a in range(n):
        for b in range(n):
            for m in range(2):
                tp = f1_counts[a, m, 0, 0] + f1_counts[b, m, 1, 0]
                fp = f1_counts[a, m, 0, 1] + f1_counts[b, m, 1, 1]
                fn = f1_counts[a, m, 0, 2] + f1_counts[b, m, 1, 2]
                f1[a, b, m] = _f1(tp, fp + fn)
    tolerant = np.empty(n)
    for b in range(n):
        right, wrong, found, missed = tolerant_counts[b]
        precision = _share(right, right + wrong)
        recall = _share(found, found + missed)
        tolerant[b] = _share(2 * precision * recall, precision + recall)
    if not (f1 != 0).any() and not (tolerant != 0).any():
        return first, first
    best0, best1 = -np.inf, -np.inf
    for i in baselines:
        best0, best1 = max(best0, f1[i, i, 0]), max(best1, f1[i, i, 1])
    scores = np.empty((n, n))
    for a in range(n):
        for b in range(n):
            if len(baselines) == 0:
                scores[a, b] = (f1[a, b, 0] + f1[a, b, 1]) + tolerant[b]
            else:
                m0 = f1[a, b, 0] - best0
                m1 = f1[a, b, 1] - best1
                m2 = tolerant[b] - tolerant[baselines[0]]
                scores[a, b] = (
                    (m0 + loss_weight * min(m0, 0.0)) + (m1 + loss_weight * min(m1, 0.0))
                ) + (m2 + loss_weight * min(m2, 0.0))
    return _first_best(scores)


@kernel
def _share(a: float, b: float) -> float:
    """``leader._ratio`` of one pair."""
    return a / b if b > 0 else 0.0
