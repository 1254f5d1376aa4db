"""Could any fixed pair of decision offsets win a recording? (issue 11)

Streams a model on a recording once (``online_rules.collect``) over a grid wide enough to reach
copy-last (occupied-cell offsets up to +20, free-cell offsets down to -20), on the last map
moved by the flow and unmoved, and reports every pair's F1 / changed-cell F1 over the whole
recording against the best baselines': how many pairs beat the best baseline's F1, the best
changed-cell F1 among those, and the best win margin of any pair. Fixed pairs chosen with
hindsight bound what the online choice of them can reach on that recording.

It also asks whether choosing *per frame*, with hindsight, between two pairs (the one with the
best F1 and the one with the best margin, moved map) could win: a choice wins when
``G1 = sum_t 2 tp - f1* (predicted + positives) >= 0`` and ``G2`` (the same over the changed
cells, with the best changed F1) ``>= 0``; each frame taking the candidate that maximises
``g1 + lam g2`` maximises ``G1 + lam G2``, so if for some ``lam >= 0`` that maximum is below
zero no per-frame choice wins. Reported per ``lam``: the best ``G1 + lam G2`` and its ``G1``,
``G2``. The same over every pair (moved and unmoved) each frame is reported for contrast.

    python experiments/pair_frontier.py -m runs/loo/cell/head_cell/positive_4/run \\
        ../shared/data/positive_4.bag --json docs/results/accuracy/positive_4/pairs_fold.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from online_rules import collect, f1

OCCUPIED = np.round(np.concatenate([np.arange(-4.8, 4.21, 0.3), [5, 6, 7, 8, 10, 12, 15, 20]]), 2)
FREE = np.round(
    np.concatenate([[-20, -15, -12, -10, -8, -6, -5, -4, -3, -2], np.arange(-1.5, 3.01, 0.3)]), 2
)


def frontier(counts: np.ndarray, best: np.ndarray) -> dict:
    """Summary of one map's pairs ``(T, A, B, 2, 3)`` against the best baselines ``(2,)``."""
    scores = f1(counts.sum(axis=0))  # (A, B, 2)
    above = scores[..., 0] > best[0]
    margins = (scores - best).min(axis=-1)
    i, j = np.unravel_index(int(np.argmax(margins)), margins.shape)
    return {
        "pairs": int(margins.size),
        "pairs_above_best_f1": int(above.sum()),
        "best_f1": float(scores[..., 0].max()),
        "best_changed_f1_of_those": float(scores[..., 1][above].max()) if above.any() else None,
        "best_margin": float(margins[i, j]),
        "best_margin_pair": [float(OCCUPIED[i]), float(FREE[j])],
        "best_margin_scores": scores[i, j].tolist(),
    }


LAMBDAS = (0.1, 0.3, 0.5, 1.0, 2.0, 3.0, 5.0, 10.0)


def hindsight(candidates: np.ndarray, best: np.ndarray) -> dict:
    """Per-frame choice between ``candidates`` ``(T, K, 2, 3)`` with hindsight (see above)."""
    tp, predicted, positives = np.moveaxis(candidates, -1, 0)  # each (T, K, 2)
    g = 2 * tp - best * (predicted + positives)  # (T, K, 2): all cells, changed cells
    rows = {}
    for lam in LAMBDAS:
        pick = (g[..., 0] + lam * g[..., 1]).argmax(axis=1)
        g1, g2 = g[np.arange(len(g)), pick].sum(axis=0)
        rows[str(lam)] = {"best": float(g1 + lam * g2), "G1": float(g1), "G2": float(g2)}
    proof = [lam for lam, r in rows.items() if r["best"] < 0]
    return {
        "lambdas": rows,
        "no_choice_wins_by_lambda": proof,
        "wins": any(r["G1"] >= 0 and r["G2"] >= 0 for r in rows.values()),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recording", type=Path)
    parser.add_argument("-m", "--model", type=Path, required=True)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    data = collect(args.model, args.recording, OCCUPIED, FREE)
    best = f1(data["baselines"].sum(axis=0)).max(axis=0)
    result = {
        "model": str(args.model),
        "recording": str(args.recording),
        "best_baselines": best.tolist(),
        "moved": frontier(data["pairs"], best),
        "unmoved": frontier(data["unmoved"], best),
    }
    scores = f1(data["pairs"].sum(axis=0))  # (A, B, 2)
    margins = (scores - best).min(axis=-1)
    two = [np.unravel_index(int(np.argmax(x)), x.shape) for x in (scores[..., 0], margins)]
    result["per_frame_hindsight"] = {
        "pairs": [[float(OCCUPIED[i]), float(FREE[j])] for i, j in two],
        **hindsight(np.stack([data["pairs"][:, i, j] for i, j in two], axis=1), best),
    }
    # Every pair, moved and unmoved, each frame: hindsight over thousands of candidates, the
    # contrast to the two above (it picks each frame's luckiest decision).
    every = np.concatenate([data["pairs"], data["unmoved"]], axis=1)
    result["per_frame_hindsight_every_pair"] = hindsight(every.reshape(len(every), -1, 2, 3), best)
    print(json.dumps(result, indent=1))
    if args.json:
        args.json.write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
