"""A new expert for the combination: does an online context table beat copy-last on movers?

The combination's ceiling (docs/research/combination_ceiling) found the experts to be its
limit. This one needs no training: per cell, counts of "occupied k frames later" given the local
binary pattern (3x3 at t, 3x3 at t and t-1; about one second ahead also a max-pooled coarse
3x3), learnt causally from the labels that have arrived (the map at t labels the prediction made
at t-k), backed off from fine contexts to coarse ones; copy-last until any label has arrived.

On each captured fold (:class:`studies.combination_ceiling.Capture`, one folder per training
seed) and horizon (k=1, K about one second), ``table`` scores, with the ceiling's margins:

- **alone**: the expert on every cell, its threshold chosen online (best all-cell F1 on the
  pairs labelled so far);
- **region**: the expert inside the causal mover region, copy-last outside, with the fixed
  threshold best for the tolerant mover margin *in hindsight* (an optimistic bound);
- copy-last and the online combination as they ran, beside them;
- **region_in_combined**: the expert in the region, the combination's map elsewhere, the
  threshold again best in hindsight (would it lift the combination's mover margin?).

    PYTHONPATH=src:. python -m studies.context_expert table runs/ceiling/s0 runs/ceiling/s1

Writes OUT/summary.{json,md}: per fold, horizon and seed the margins, and the mean over seeds.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from studies.combination_ceiling import Capture, margins_text
from studies.harness import DEVELOPMENT, parse, parser, stem, write_summary

PRIOR = 0.05  # the occupancy the coarsest context starts from
THRESHOLDS = (0.05, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7)  # the region's, chosen in hindsight
BINS = 50  # the online threshold's resolution
COLUMNS = ("alone", "region", "copy_last", "model_combined", "region_in_combined")


def context_codes(occupied: np.ndarray, radius: int, lags: Sequence[int], pool: int) -> np.ndarray:
    """Each cell's local pattern ``(T, H, W)`` int64 of ``occupied`` ``(T, H, W)`` bool.

    Bit ``i * (2r+1)**2 + (dy+r) * (2r+1) + (dx+r)`` is the cell at offset ``(dy, dx)`` of frame
    ``t - lags[i]`` (row-major: bit 0 is the top-left of the first lag). With ``pool`` > 1 the
    maps are max-pooled in ``pool`` x ``pool`` blocks first and the offsets step whole blocks
    (H and W must be multiples of ``pool``). Cells outside the grid and frames before the first
    read as free."""
    T, H, W = occupied.shape
    o = occupied.astype(bool)
    if pool > 1:
        o = o.reshape(T, H // pool, pool, W // pool, pool).max(axis=(2, 4))
        o = o.repeat(pool, 1).repeat(pool, 2)
    m = radius * pool
    padded = np.pad(o, ((0, 0), (m, m), (m, m)))
    code = np.zeros((T, H, W), np.int64)
    bit = 0
    for lag in lags:
        src = np.zeros_like(padded)
        src[lag:] = padded[: T - lag]
        for dy in range(-radius, radius + 1):
            for dx in range(-radius, radius + 1):
                y, x = m + dy * pool, m + dx * pool
                code |= src[:, y : y + H, x : x + W].astype(np.int64) << bit
                bit += 1
    return code


def levels_for(occupied: np.ndarray, k: int) -> list[np.ndarray]:
    """The contexts, coarse to fine: the cell, its 3x3, its 3x3 at t and t-1; for k > 1 also
    the 3x3 of 4x4 blocks after the cell."""
    fine = ((0, (0,)), (1, (0,)), (1, (0, 1)))
    levels = [context_codes(occupied, r, lags, 1) for r, lags in fine]
    if k > 1:
        levels.insert(1, context_codes(occupied, 1, (0,), 4))
    return levels


def online_probability(
    occupied: np.ndarray, k: int, levels: Sequence[np.ndarray], prior_weight: float
) -> np.ndarray:
    """The probability ``(T, H, W)`` that each cell is occupied k frames after t, from the
    counts of the pairs labelled by t (codes at s, map at s + k, s + k <= t). Each level
    (coarse to fine) shrinks its count towards the coarser estimate with ``prior_weight``
    pseudo-counts. NaN where the coarsest context has no label yet."""
    T = len(occupied)
    sizes = [int(c.max()) + 1 for c in levels]  # only sizes the tables: no values read ahead
    seen = [np.zeros(n) for n in sizes]
    hits = [np.zeros(n) for n in sizes]
    out = np.empty(occupied.shape, np.float64)
    for t in range(T):
        if t >= k:  # frame t labels what was predicted at t - k
            label = occupied[t].ravel().astype(np.float64)
            for c, n, n1, size in zip(levels, seen, hits, sizes, strict=True):
                past = c[t - k].ravel()
                n += np.bincount(past, minlength=size)
                n1 += np.bincount(past, weights=label, minlength=size)
        p = np.full(occupied.shape[1:], PRIOR)
        for c, n, n1 in zip(levels, seen, hits, strict=True):
            p = (n1[c[t]] + prior_weight * p) / (n[c[t]] + prior_weight)
        p[seen[0][levels[0][t]] == 0] = np.nan
        out[t] = p
    return out


def online_decided(probability: np.ndarray, occupied: np.ndarray, k: int) -> np.ndarray:
    """``probability`` decided with the threshold best for all-cell F1 on the pairs labelled by
    t (:data:`BINS` levels); copy-last (``occupied[t]``) where it is NaN."""
    known = ~np.isnan(probability)
    q = np.minimum((np.nan_to_num(probability) * BINS).astype(int), BINS - 1)
    pos, neg = np.zeros(BINS), np.zeros(BINS)
    out = np.empty(probability.shape, bool)
    for t in range(len(probability)):
        if t >= k:
            label, use = occupied[t], known[t - k]
            pos += np.bincount(q[t - k][use & label], minlength=BINS)
            neg += np.bincount(q[t - k][use & ~label], minlength=BINS)
        tp, fp = np.cumsum(pos[::-1])[::-1], np.cumsum(neg[::-1])[::-1]
        f1 = 2 * tp / np.maximum(tp + fp + pos.sum(), 1)  # 2tp / (2tp + fp + fn)
        threshold = int(np.argmax(f1)) if pos.sum() else BINS // 2
        out[t] = np.where(known[t], q[t] >= threshold, occupied[t])
    return out


def _hindsight(cap: Any, at: int, p: np.ndarray, outside: np.ndarray) -> tuple[list, float]:
    """The expert's ``p`` decided in the causal mover region, ``outside`` elsewhere: the margins
    with the threshold (:data:`THRESHOLDS`) best for the mover margin, and the threshold."""
    inside = cap.causal_region & ~np.isnan(p)
    scored = {th: cap.margins(np.where(inside, p >= th, outside), at) for th in THRESHOLDS}
    best = max(THRESHOLDS, key=lambda th: scored[th][2])
    return scored[best].tolist(), best


def fold_scores(cap: Any, at: int, probability: np.ndarray) -> dict[str, Any]:
    """The margins of each column (:data:`COLUMNS`) on ``cap`` at ``at`` (0: k=1, 1: K), the
    expert's ``probability`` over all the recording's frames, and the thresholds in hindsight."""
    k = 1 if at == 0 else cap.horizon
    alone = online_decided(probability, cap.occupied, k)[cap.scored]
    p = probability[cap.scored]
    copy_last = cap.methods["copy_last"][:, at]
    combined = cap.methods["model_combined"][:, at]
    region, threshold = _hindsight(cap, at, p, copy_last)
    in_combined, threshold_combined = _hindsight(cap, at, p, combined)
    return {
        "alone": cap.margins(alone, at).tolist(),
        "region": region,
        "threshold": threshold,
        "copy_last": cap.margins(copy_last, at).tolist(),
        "model_combined": cap.margins(combined, at).tolist(),
        "region_in_combined": in_combined,
        "threshold_in_combined": threshold_combined,
    }


def seed_scores(folder: Path, prior_weight: float) -> dict[str, dict[str, Any]]:
    """``{fold: {"0"/"1": fold_scores, "K": horizon}}`` for every capture in ``folder``."""
    out: dict[str, dict[str, Any]] = {}
    for path in sorted(folder.glob("*.npz")):
        cap = Capture(path)
        row: dict[str, Any] = {"K": cap.horizon}
        for at in (0, 1):
            k = 1 if at == 0 else cap.horizon
            p = online_probability(cap.occupied, k, levels_for(cap.occupied, k), prior_weight)
            row[str(at)] = fold_scores(cap, at, p)
        out[cap.name] = row
        print(f"{folder}/{cap.name}: done", flush=True)
    return out


def mean_over_seeds(seeds: list[dict[str, dict[str, Any]]]) -> dict[str, Any]:
    """Per ``fold@at``: each column's margins, mean and per seed, and the region's thresholds."""
    order = {stem(name): i for i, name in enumerate(DEVELOPMENT)}
    rows: dict[str, Any] = {}
    for fold in sorted(seeds[0], key=lambda f: (order.get(f, len(order)), f)):
        for at in ("0", "1"):
            per = [s[fold][at] for s in seeds]
            row: dict[str, Any] = {"K": seeds[0][fold]["K"] if at == "1" else 1}
            for c in COLUMNS:
                m = np.array([p[c] for p in per])
                row[c] = {"margins": m.mean(0).tolist(), "seeds": m.tolist()}
            row["thresholds"] = [p["threshold"] for p in per]
            row["thresholds_in_combined"] = [p["threshold_in_combined"] for p in per]
            rows[f"{fold}@{at}"] = row
    return rows


def markdown(rows: dict[str, Any]) -> str:
    """Per fold and horizon, then aggregated: margins (all-cell / changed / tolerant mover);
    the spread between seeds of the mover margin: the expert's (alone and region), the
    combination's, the expert's in the combination."""
    head = "| fold | k | alone | region (th) | copy_last | model_combined | region_in_combined (th)"
    lines = [head + " | seeds' mover spread |", "|---" * 8 + "|"]
    for key, r in rows.items():
        fold = key.split("@")[0]
        ptp = {c: np.ptp([m[2] for m in r[c]["seeds"]]) for c in COLUMNS}
        spread = f"{max(ptp['alone'], ptp['region']):.3f} / {ptp['model_combined']:.3f} / "
        spread += f"{ptp['region_in_combined']:.3f}"
        th = "/".join(str(t) for t in r["thresholds"])
        cells = [margins_text(r["alone"]["margins"])]
        cells.append(f"{margins_text(r['region']['margins'])} ({th})")
        cells += [margins_text(r[c]["margins"]) for c in ("copy_last", "model_combined")]
        th = "/".join(str(t) for t in r["thresholds_in_combined"])
        cells.append(f"{margins_text(r['region_in_combined']['margins'])} ({th})")
        lines.append(f"| {fold} | {r['K']} | " + " | ".join(cells) + f" | {spread} |")
    lines += ["", "| column | at | mean margins | worst fold | folds won |", "|---" * 5 + "|"]
    for at in ("0", "1"):
        for c in COLUMNS:
            m = np.array([r[c]["margins"] for key, r in rows.items() if key.endswith("@" + at)])
            won = int((m > 0).all(axis=1).sum())
            when = "k=1" if at == "0" else "~1 s"
            lines.append(f"| {c} | {when} | {margins_text(m.mean(0))} | {margins_text(m.min(0))} | "
                         f"{won}/{len(m)} |")  # fmt: skip
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    p = parser("context_expert", __doc__)
    p.add_argument("command", choices=("table",))
    p.add_argument("dirs", nargs="+", type=Path, help="captures, one folder per training seed")
    p.add_argument("--prior-weight", type=float, default=2.0)
    args = parse(p, argv)
    rows = mean_over_seeds([seed_scores(d, args.prior_weight) for d in args.dirs])
    write_summary(args, "summary", rows, markdown(rows))
    return rows


if __name__ == "__main__":
    main()
