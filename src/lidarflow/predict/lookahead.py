"""Which pair of decision offsets the online decision takes (:mod:`lidarflow.predict.decision`):
each candidate's win margin if the next frames went as its recent ones did, after the decisions
made, and the candidate that leaves it largest. Compiled where available, the same choice."""

from __future__ import annotations

import numpy as np

from lidarflow.compiled import kernel, ready

__all__ = ["best_candidate", "f1_from_counts", "lookahead_terms"]


def f1_from_counts(tp: np.ndarray, predicted: np.ndarray, positives: np.ndarray) -> np.ndarray:
    """F1 from counts (arrays alike): ``2TP / (2TP + FP + FN) = 2TP / (predicted + positives)``,
    1 where there is nothing to find and nothing predicted (as ``metrics.Counts.f1``)."""
    denominator = predicted + positives
    return np.where(denominator > 0, 2.0 * tp / np.maximum(denominator, 1e-12), 1.0)


def lookahead_terms(
    made: np.ndarray,
    recent: np.ndarray,
    weight: float,
    baselines: np.ndarray,
    lookahead: float,
) -> np.ndarray:
    """``(2, *pairs)``: the F1 and changed-cell F1 (first axis) less the best baseline's, if
    ``lookahead`` more frames went as each candidate's recent ones did, after the decisions
    made. Counts are ``(tp, predicted, positives)`` on the last axis, over all cells and over
    the changed ones on the first: ``made`` ``(2, 3)`` and ``baselines`` ``(2, n, 3)`` over the
    stream so far, ``recent`` ``(2, *pairs, 3)`` decayed, ``weight`` frames' worth of them.
    With ``made`` zero it is each candidate's own recent margin."""
    extra = (1,) * (recent.ndim - 2)
    h = lookahead / weight  # the recent counts per frame, h frames of them
    f1 = f1_from_counts(*np.moveaxis(made.reshape(2, *extra, 3) + h * recent, -1, 0))
    best = f1_from_counts(*np.moveaxis(baselines, -1, 0)).max(axis=1)
    return f1 - best.reshape(2, *extra)


def best_candidate(
    made: np.ndarray,
    tp: np.ndarray,
    predicted: np.ndarray,
    positives: np.ndarray,
    weight: float,
    baselines: np.ndarray,
    lookahead: float,
    tie_break: float,
) -> int:
    """The flat index into ``tp``'s shape ``(2, *pairs)`` less its first axis of the candidate
    whose :func:`lookahead_terms` ``t`` (``recent``: ``tp``, ``predicted`` and ``positives``
    ``(2,)`` broadcast) make ``min(t) + tie_break * sum(t)`` over the first axis largest, the
    first of equals. Compiled where available, the same choice."""
    args = (made, tp.reshape(2, -1), predicted.reshape(2, -1), positives, weight, baselines,
            lookahead, tie_break)  # fmt: skip
    if ready(_best_candidate_loop, *args):
        return int(_best_candidate_loop(*args))
    recent = np.stack([tp, predicted, np.broadcast_to(
        positives.reshape(2, *(1,) * (tp.ndim - 1)), tp.shape)], axis=-1)  # fmt: skip
    terms = lookahead_terms(made, recent, weight, baselines, lookahead)
    return int(np.argmax(terms.min(axis=0) + tie_break * terms.sum(axis=0)))


@kernel
def _f1(tp: float, predicted: float, positives: float) -> float:
    """:func:`f1_from_counts` of one count."""
    denominator = predicted + positives
    return 2.0 * tp / max(denominator, 1e-12) if denominator > 0 else 1.0


@kernel
def _best_candidate_loop(
    made: np.ndarray,
    tp: np.ndarray,
    predicted: np.ndarray,
    positives: np.ndarray,
    weight: float,
    baselines: np.ndarray,
    lookahead: float,
    tie_break: float,
) -> int:
    """:func:`best_candidate` over ``tp``, ``predicted`` ``(2, candidates)``, each term formed
    as :func:`lookahead_terms` forms it (``made + h * recent``, then F1, less the best
    baseline's)."""
    h = lookahead / weight
    best = np.empty(2)
    for k in range(2):
        best[k] = -np.inf
        for n in range(baselines.shape[1]):
            best[k] = max(best[k], _f1(baselines[k, n, 0], baselines[k, n, 1], baselines[k, n, 2]))
    chosen, top = 0, -np.inf
    for c in range(tp.shape[1]):
        t0 = _f1(made[0, 0] + h * tp[0, c], made[0, 1] + h * predicted[0, c],
                 made[0, 2] + h * positives[0]) - best[0]  # fmt: skip
        t1 = _f1(made[1, 0] + h * tp[1, c], made[1, 1] + h * predicted[1, c],
                 made[1, 2] + h * positives[1]) - best[1]  # fmt: skip
        score = min(t0, t1) + tie_break * (t0 + t1)
        if score > top or c == 0:
            chosen, top = c, score
    return chosen
