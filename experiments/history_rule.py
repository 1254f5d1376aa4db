"""How far can a cell's own history go? A reference point for issue 11's ablation.

Fit ``P(O^{t+1} = 1 | the cell's last K values)`` (a table of 2^K counts, no network, no
neighbours, no flow) on training recordings, then predict held-out recordings with it at the
design's threshold 0.4 and score F1 and changed-cell F1 exactly as `lidarflow evaluate` does
(frames t >= 10 predicted, every cell of the 100 x 100 grid). It shows what calibrated,
history-only decisions give: where they beat copy-last in F1, and how low their changed-cell
F1 stays beside the temporal average's.

    python experiments/history_rule.py --train ../shared/data/positive_{1,3,4}.bag \\
        --eval ../shared/data/positive_2.bag --k 3 5 8 --json history_rule.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from lidarflow.data import load_any
from lidarflow.evaluate.metrics import f1_score
from lidarflow.scan import GridSpec

WARMUP = 10
THRESHOLD = 0.4


def history_codes(occupancy: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Per cell and frame ``t >= k - 1``: the code of ``O^{t-k+1} .. O^t`` (bits, oldest
    first) and the target ``O^{t+1}``; frames ``k - 1 .. N - 2``."""
    o = occupancy.astype(np.int64)
    code = np.zeros_like(o[k - 1 : -1])
    for j in range(k):
        code = code * 2 + o[j : len(o) - k + j]
    return code, occupancy[k:].astype(bool)


def fit(recordings: list[np.ndarray], k: int) -> np.ndarray:
    """``P(next occupied | code)`` for the ``2^k`` codes (0 where a code was never seen)."""
    ones, total = np.zeros(2**k), np.zeros(2**k)
    for occupancy in recordings:
        code, target = history_codes(occupancy, k)
        np.add.at(total, code.ravel(), 1)
        np.add.at(ones, code.ravel(), target.ravel())
    return ones / np.maximum(total, 1)


def score(table: np.ndarray, occupancy: np.ndarray, k: int) -> dict[str, float]:
    code, target = history_codes(occupancy, k)
    skip = max(0, WARMUP - (k - 1))  # code index i predicts frame k + i from frame k - 1 + i
    code, target = code[skip:], target[skip:]
    current = occupancy[k - 1 : -1][skip:].astype(bool)
    predicted = table[code] >= THRESHOLD
    changed = current != target
    return {
        "f1": f1_score(predicted, target),
        "changed_f1": f1_score(predicted[changed], target[changed]),
        "copy_last_f1": f1_score(current, target),
        "frames": len(target),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--train", type=Path, nargs="+", required=True)
    parser.add_argument("--eval", type=Path, nargs="+", required=True)
    parser.add_argument("--k", type=int, nargs="+", default=[3, 5, 8])
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    if set(args.train) & set(args.eval):
        parser.error("evaluate on recordings that were not fitted on")
    grid = GridSpec()
    train = [load_any(p).maps(grid)[0] for p in args.train]
    held = {p.name: load_any(p).maps(grid)[0] for p in args.eval}
    results: dict[str, dict] = {}
    for k in args.k:
        table = fit(train, k)
        for name, occupancy in held.items():
            r = score(table, occupancy, k)
            results.setdefault(f"K={k}", {})[name] = r
            print(
                f"K={k} {name:42s} F1 {r['f1']:.4f}  changed F1 {r['changed_f1']:.4f}  "
                f"(copy-last F1 {r['copy_last_f1']:.4f})"
            )
    if args.json:
        payload = {"train": [str(p) for p in args.train], "threshold": THRESHOLD,
                   "warmup": WARMUP, "results": results}  # fmt: skip
        args.json.write_text(json.dumps(payload, indent=2))


if __name__ == "__main__":
    main()
