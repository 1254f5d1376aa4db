"""Counting the decisions every pair of offsets would make, cheaply (:mod:`lidarflow.predict.
decision`'s arithmetic).

Counting every pair is cheap because a cell's decision depends on one offset alone unless the
moved map is fractional there: a free cell is predicted occupied iff ``b >= threshold_logit -
logit``, an occupied one iff ``a >= ...``, so one sorted search per offset grid counts all pairs;
only the few fractional cells are counted pair by pair. NumPy only: the ONNX Predictor runs
without PyTorch. The logits the offsets shift are :mod:`lidarflow.predict.logits`'.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from lidarflow.compiled import available, kernel, ready
from lidarflow.geometry import warp_map

__all__ = [
    "THRESHOLD",
    "counts",
    "counts_all_and_changed",
    "moved_last_map",
    "pair_counts",
    "pair_counts_each",
    "pair_counts_within",
]

#: The project's decision threshold: a cell is predicted occupied where its probability is at
#: least this (design notes §1 and §5).
THRESHOLD = 0.4


def counts(predicted: np.ndarray, target: np.ndarray, mask: np.ndarray) -> tuple[int, int, int]:
    """``(true positives, predicted, positives)`` of boolean maps within ``mask``: the form
    every count of the online decision takes (F1 is ``2TP / (predicted + positives)``)."""
    p, t = predicted & mask, target & mask
    return (
        int(np.count_nonzero(p & t)),
        int(np.count_nonzero(p)),
        int(np.count_nonzero(t)),
    )


def counts_all_and_changed(
    predictions: list[np.ndarray], target: np.ndarray, changed: np.ndarray
) -> np.ndarray:
    """``(2, P, 3)``: :func:`counts` of each of ``predictions`` (bool maps) over all cells
    (first row) and over the ``changed`` ones (second), from one product of 0/1 columns
    (integers, exact in float64): twenty-four counts a frame were as many passes over the map.
    Compiled where available (bool predictions), one pass, the same counts."""
    t, c = np.ravel(target).astype(bool), np.ravel(changed).astype(bool)
    if available() and predictions and all(p.dtype == bool for p in predictions):
        out = np.zeros((2, len(predictions), 3))
        stacked = np.array([np.ravel(p) for p in predictions])  # (np.stack: 2.5x the time)
        args = (stacked.view(np.uint8), t.view(np.uint8), c.view(np.uint8), out)
        if ready(_table_loop, *args):
            _table_loop(*args)
            return out
    columns = np.stack([t, np.ones_like(t), t & c, c], axis=1).astype(np.float64)
    stacked = np.stack([np.ravel(p) for p in predictions]).astype(np.float64)
    product = _one_thread_product(stacked, columns)  # (P, [tp, predicted] x [all, changed])
    positives = np.array([np.count_nonzero(t), np.count_nonzero(t & c)], np.float64)
    out = np.empty((2, len(predictions), 3))
    out[:, :, :2] = product.reshape(len(predictions), 2, 2).transpose(1, 0, 2)
    out[:, :, 2] = positives[:, None]
    return out


@kernel
def _table_loop(
    predictions: np.ndarray, target: np.ndarray, changed: np.ndarray, out: np.ndarray
) -> None:
    """:func:`counts_all_and_changed`'s table into ``out`` ``(2, P, 3)`` for 0/1 (bool's bytes)
    ``predictions`` ``(P, cells)``, ``target`` and ``changed`` ``(cells,)``: one pass a row."""
    positives, changed_positives = 0, 0
    for c in range(len(target)):
        positives += target[c]
        changed_positives += target[c] & changed[c]
    for p in range(predictions.shape[0]):
        tp, predicted, changed_tp, changed_predicted = 0, 0, 0, 0
        for c in range(len(target)):
            x = predictions[p, c]
            predicted += x
            tp += x & target[c]
            changed_predicted += x & changed[c]
            changed_tp += x & target[c] & changed[c]
        out[0, p, 0], out[0, p, 1], out[0, p, 2] = tp, predicted, positives
        out[1, p, 0], out[1, p, 1] = changed_tp, changed_predicted
        out[1, p, 2] = changed_positives


def moved_last_map(
    occupancy: np.ndarray,
    backward_flow: np.ndarray | None,
    warp: Callable[[np.ndarray, np.ndarray], np.ndarray] = warp_map,
) -> np.ndarray:
    """``clamp(W(O^t, B^t), 0, 1)`` ``(H, W)``: the last map moved into the next frame, the
    split of :meth:`~lidarflow.models.LidarFlowNet.predict_next`; ``O^t`` itself without a flow.

    NumPy (the ONNX Predictor runs without PyTorch): ``warp`` is
    :func:`lidarflow.geometry.warp_map` or one that computes the same, faster on a stream
    (:class:`lidarflow.geometry.FlowWarp`).
    """
    if backward_flow is None:
        return np.clip(np.asarray(occupancy, np.float64), 0.0, 1.0)
    return np.clip(warp(occupancy, backward_flow), 0.0, 1.0)


def _at_least(values: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """For each offset, how many of ``values`` are ``<= offset``. Only the values at most the
    largest offset are sorted: most cells' logits are far from every offset's threshold
    (a free cell at 0.01 never flips), and sorting them all was most of the counting's cost."""
    if len(offsets) == 0:
        return np.zeros(0, np.intp)
    values = values[values <= offsets.max()]
    return np.searchsorted(np.sort(values), offsets, side="right")


def pair_counts(
    need: np.ndarray,
    moved: np.ndarray,
    target: np.ndarray,
    occupied_offsets: np.ndarray,
    free_offsets: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, int]:
    """``(true positives (A, B), predicted (A, B), positives)`` over the given cells.

    A cell is predicted occupied under the pair ``(a, b)`` when ``moved * a + (1 - moved) * b
    >= need`` (``need``: the logit the threshold asks for minus the model's own logit);
    ``moved`` in [0, 1] is the last map moved into the next frame; ``target`` bool.
    """
    need, moved, target = (np.ravel(x) for x in (need, moved, target))
    a, b = np.asarray(occupied_offsets, np.float64), np.asarray(free_offsets, np.float64)
    free, occupied = moved <= 0.0, moved >= 1.0
    fractional = ~(free | occupied)
    tp = _at_least(need[occupied & target], a)[:, None] + _at_least(need[free & target], b)
    predicted = _at_least(need[occupied], a)[:, None] + _at_least(need[free], b)
    if fractional.any():
        w, n, t = moved[fractional], need[fractional], target[fractional]
        # Pair by pair only where the pairs disagree: a cell below its smallest pair's value
        # is hit by every pair, one above its largest by none (rounding is monotone, so these
        # two are exactly the extremes of the products below).
        always = n <= w * a.min() + (1.0 - w) * b.min()
        some = ~always & (n <= w * a.max() + (1.0 - w) * b.max())
        tp = tp + np.count_nonzero(always & t)
        predicted = predicted + np.count_nonzero(always)
        w, n, t = w[some], n[some], t[some]
        hit = w * a[:, None, None] + (1.0 - w) * b[None, :, None] >= n  # (A, B, cells)
        tp = tp + np.count_nonzero(hit & t, axis=-1)
        predicted = predicted + np.count_nonzero(hit, axis=-1)
    return tp, predicted, int(np.count_nonzero(target))


def _upto(cells: np.ndarray, indicator: np.ndarray | None, ends: np.ndarray) -> np.ndarray:
    """For each end, how many of the first ``end`` ``cells`` the ``indicator`` (flat, bool;
    ``None``: every cell) holds."""
    if indicator is None:
        return ends
    return np.concatenate([[0], np.cumsum(indicator[cells])])[ends]


# OpenBLAS wakes a thread per core above m * n * k = 65536 * 4, and beside a busy process its
# threads wait on each other (predict/headstep.py): a product this small stays on one thread,
# in slices along the summed axis (integer-valued floats: the sum is exact in any order).
_SINGLE_THREAD_MNK = 65536 * 2


def _one_thread_product(left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """``left @ right`` (integer-valued float64), computed on one thread."""
    step = max(16, _SINGLE_THREAD_MNK // max(1, left.shape[0] * right.shape[1]))
    out = np.zeros((left.shape[0], right.shape[1]))
    for start in range(0, left.shape[1], step):
        out += left[:, start : start + step] @ right[start : start + step]
    return out


def _pair_hits(
    w: np.ndarray, n: np.ndarray, a: np.ndarray, b: np.ndarray, columns: np.ndarray
) -> np.ndarray:
    """``(A, B, M)`` int64: per pair ``(a_i, b_j)``, the sum of each of ``columns`` ``(cells,
    M)`` (bool) over the cells it predicts occupied (``w a_i + (1 - w) b_j >= n``)."""
    hit = w * a[:, None, None] + (1.0 - w) * b[None, :, None] >= n  # (A, B, cells)
    # Every column's counts of the pairs' hits in one product of 0/1 columns (integers, exact
    # in float64): counting the (A, B, cells) cube once per column was most of this.
    cube = hit.reshape(len(a) * len(b), len(w)).astype(np.float64)
    summed = _one_thread_product(cube, columns.astype(np.float64))
    return summed.astype(np.int64).reshape(len(a), len(b), -1)


@kernel
def _counts_loop(
    need: np.ndarray,
    moved: np.ndarray,
    kinds: np.ndarray,
    a: np.ndarray,
    b: np.ndarray,
    out: np.ndarray,
) -> None:
    """:func:`pair_counts_within`'s counts into ``out`` ``(K, A + 1 + B + 1 + 1 + A (B + 1))``
    (zeros) for the 0/1 columns ``kinds`` ``(cells, K)``: per kind, the occupied cells by the
    first offset of ``a`` (sorted) that predicts them, the free ones likewise by ``b``, the
    fractional cells every pair predicts, then per ``a_i`` the fractional cells only some
    pairs predict, by the first ``b_j`` that does (the counts are their running sums)."""
    na, nb = len(a), len(b)
    free_at, every_at, pairs_at = na + 1, na + nb + 2, na + nb + 3
    for c in range(len(need)):
        w, n = moved[c], need[c]
        # (a cell beyond its side's largest offset flips under no pair: its slot, one past
        # the side's offsets, is never read, so it is not counted at all)
        if w <= 0.0:
            if n > b[nb - 1]:
                continue
            slot = free_at + np.searchsorted(b, n)
        elif w >= 1.0:
            if n > a[na - 1]:
                continue
            slot = np.searchsorted(a, n)
        elif n <= w * a[0] + (1.0 - w) * b[0]:
            slot = every_at
        elif n <= w * a[na - 1] + (1.0 - w) * b[nb - 1]:
            free, low = 1.0 - w, nb
            for i in range(na):
                # the pairs (a_i, b_j) that predict the cell are those from the first j on
                # (rounding is monotone), and that j does not grow with i (a increasing): found
                # by stepping down from a_(i-1)'s on the same expression
                wa = w * a[i]
                while low > 0 and wa + free * b[low - 1] >= n:
                    low -= 1
                for k in range(kinds.shape[1]):
                    out[k, pairs_at + i * (nb + 1) + low] += kinds[c, k]
            continue
        else:
            continue
        for k in range(kinds.shape[1]):
            out[k, slot] += kinds[c, k]


@kernel
def _running_sums(out: np.ndarray, na: int, nb: int, counts: np.ndarray) -> None:
    """``counts`` ``(K, A, B)``: each pair's count from :func:`_counts_loop`'s ``out``, the
    running sums of its occupied, free and some-pairs slots plus its every-pair slot."""
    every_at, pairs_at = na + nb + 2, na + nb + 3
    for k in range(out.shape[0]):
        occupied = 0
        for i in range(na):
            occupied += out[k, i]
            free, pairs = 0, 0
            for j in range(nb):
                free += out[k, na + 1 + j]
                pairs += out[k, pairs_at + i * (nb + 1) + j]
                counts[k, i, j] = occupied + free + out[k, every_at] + pairs


def _pair_counts_compiled(
    needs: list[np.ndarray],
    moveds: list[np.ndarray],
    target: np.ndarray,
    masks: list[np.ndarray | None],
    a: np.ndarray,
    b: np.ndarray,
) -> list[list[tuple[np.ndarray, np.ndarray, int]]] | None:
    """:func:`pair_counts_each` by :func:`_counts_loop` (``a``, ``b`` sorted, not empty; flat
    maps); ``None`` while the loop is not compiled yet (:func:`lidarflow.compiled.ready`). The
    masks' columns are the same for every map: built once."""
    kinds = []
    for mask in masks:
        kinds += [target, np.ones_like(target)] if mask is None else [target & mask, mask]
    # (cells, K) as the kernel reads it, a transposed view: np.stack along axis 1 cost more
    # than the loop itself
    columns = np.array(kinds).T.view(np.uint8)
    positives = [int(np.count_nonzero(kinds[2 * i])) for i in range(len(masks))]
    na, nb = len(a), len(b)
    out = np.zeros((len(kinds), na + nb + 3 + na * (nb + 1)), np.int64)
    counted = []
    for need, moved in zip(needs, moveds, strict=True):
        counts = np.empty((len(kinds), na, nb), np.int64)
        # both asked for at once, so that both compile from the first call on
        if not all([ready(_counts_loop, need, moved, columns, a, b, out),
                    ready(_running_sums, out, na, nb, counts)]):  # fmt: skip
            return None
        out[:] = 0
        _counts_loop(need, moved, columns, a, b, out)
        _running_sums(out, na, nb, counts)
        counted.append(
            [(counts[2 * i], counts[2 * i + 1], positives[i]) for i in range(len(masks))]
        )
    return counted


def pair_counts_each(
    needs: list[np.ndarray],
    moveds: list[np.ndarray],
    target: np.ndarray,
    masks: list[np.ndarray | None],
    occupied_offsets: np.ndarray,
    free_offsets: np.ndarray,
) -> list[list[tuple[np.ndarray, np.ndarray, int]]]:
    """:func:`pair_counts_within` of each ``(need, moved)`` of ``needs`` and ``moveds`` (the
    maps a decision tries: one list per map), the same ``target`` and ``masks`` for all: what
    only the target and masks decide is done once."""
    if len(needs) != len(moveds):
        raise ValueError(f"need as many needs as moved maps, got {len(needs)} and {len(moveds)}")
    target = np.ravel(target)
    a, b = np.asarray(occupied_offsets, np.float64), np.asarray(free_offsets, np.float64)
    # (a[1:] > a[:-1]: np.diff(a) > 0 without its overhead, the same for every float)
    ordered = len(a) and len(b) and (a[1:] > a[:-1]).all() and (b[1:] > b[:-1]).all()
    if available() and ordered:
        counted = _pair_counts_compiled(
            [np.asarray(np.ravel(n), np.float64) for n in needs],
            [np.asarray(np.ravel(m), np.float64) for m in moveds],
            np.asarray(target, bool),
            [None if m is None else np.asarray(np.ravel(m), bool) for m in masks],
            a,
            b,
        )
        if counted is not None:
            return counted
    return [
        _pair_counts_numpy(np.ravel(n), np.ravel(m), target, masks, a, b)
        for n, m in zip(needs, moveds, strict=True)
    ]


def pair_counts_within(
    need: np.ndarray,
    moved: np.ndarray,
    target: np.ndarray,
    masks: list[np.ndarray | None],
    occupied_offsets: np.ndarray,
    free_offsets: np.ndarray,
) -> list[tuple[np.ndarray, np.ndarray, int]]:
    """:func:`pair_counts` over the cells of each of ``masks`` (bool, ``None``: all cells), in
    one pass: the online decision counts every frame over all cells and over the changed ones,
    and most of the work (which cells an offset can flip, sorted by ``need``) is the same.
    Compiled where available (offsets increasing), the same counts."""
    return pair_counts_each([need], [moved], target, masks, occupied_offsets, free_offsets)[0]


def _pair_counts_numpy(
    need: np.ndarray,
    moved: np.ndarray,
    target: np.ndarray,
    masks: list[np.ndarray | None],
    a: np.ndarray,
    b: np.ndarray,
) -> list[tuple[np.ndarray, np.ndarray, int]]:
    """:func:`pair_counts_within` in NumPy (the reference) over flat maps, ``a`` and ``b``
    float64."""
    free, occupied = moved <= 0.0, moved >= 1.0
    # Per side: the cells at most its largest offset (the rest flip under no pair), sorted by
    # need, and how many of them each offset predicts occupied.
    sides = []
    for side, offsets in ((occupied, a), (free, b)):
        cells = np.flatnonzero(side & (need <= offsets.max()))
        cells = cells[np.argsort(need[cells], kind="stable")]
        sides.append((cells, np.searchsorted(need[cells], offsets, side="right")))
    fractional = np.flatnonzero(~(free | occupied))
    masks = [None if m is None else np.ravel(m) for m in masks]
    hits = [target if m is None else target & m for m in masks]
    every = np.ones(len(fractional), bool)
    # per mask: (hits, cells) on the fractional cells
    on = [
        (h[fractional], every if m is None else m[fractional])
        for h, m in zip(hits, masks, strict=True)
    ]
    extra: list[tuple[np.ndarray | int, np.ndarray | int]] = [(0, 0)] * len(masks)
    if len(fractional):  # pair by pair where the pairs disagree (as pair_counts)
        w, n = moved[fractional], need[fractional]
        always = n <= w * a.min() + (1.0 - w) * b.min()
        some = ~always & (n <= w * a.max() + (1.0 - w) * b.max())
        w, n = w[some], n[some]
        columns = np.stack([c[some] for pair in on for c in pair], axis=1)
        summed = _pair_hits(w, n, a, b, columns)
        extra = [
            (
                np.count_nonzero(always & t) + summed[..., 2 * i],
                np.count_nonzero(always & m) + summed[..., 2 * i + 1],
            )
            for i, (t, m) in enumerate(on)
        ]
    out = []
    (oc, o_ends), (fc, f_ends) = sides
    for mask, h, (tp_extra, predicted_extra) in zip(masks, hits, extra, strict=True):
        tp = _upto(oc, h, o_ends)[:, None] + _upto(fc, h, f_ends) + tp_extra
        predicted = _upto(oc, mask, o_ends)[:, None] + _upto(fc, mask, f_ends) + predicted_extra
        out.append((tp, predicted, int(np.count_nonzero(h))))
    return out
