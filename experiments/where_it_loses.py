"""Where in a recording does a model lose against copy-last? (issue 11, positive_4)

Streams the model as `lidarflow evaluate` does (its fixed decision offset, probability >= 0.4)
and prints, per stretch of frames, its F1 beside copy-last's with both false-positive and
false-negative counts; then the cells with the most false positives in the last stretch, each
with how often it was occupied before that stretch and during it (a static structure that
moved shows as a cell occupied nearly always before and much less after).

    python experiments/where_it_loses.py -m runs/loo/cell/head_cell/positive_4/run \\
        ../shared/data/positive_4.bag --stretches 10 100 200 250 306
"""

from __future__ import annotations

import argparse
import itertools
from pathlib import Path

import numpy as np
from history_rule import model_probabilities

from lidarflow.data import load_any
from lidarflow.evaluate.metrics import THRESHOLD, confusion
from lidarflow.scan import GridSpec


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recording", type=Path)
    parser.add_argument("-m", "--model", type=Path, required=True)
    parser.add_argument(
        "--stretches", type=int, nargs="+", required=True, help="frame boundaries, ascending"
    )
    parser.add_argument("--top", type=int, default=10, help="false-positive cells to list")
    args = parser.parse_args()
    recording = load_any(args.recording)
    occupancy, visibility = recording.maps(GridSpec())
    probability = model_probabilities(args.model, recording, (occupancy, visibility))
    occupied = occupancy.astype(bool)
    bounds = sorted({b for b in args.stretches if b < len(occupied) - 1} | {len(occupied) - 1})
    for start, end in itertools.pairwise(bounds):
        t = np.arange(max(start, 10), end)
        target = occupied[t + 1]
        model = confusion(probability[t] >= THRESHOLD, target)
        copy = confusion(occupied[t], target)
        print(
            f"frames {t[0]}-{t[-1]}: model F1 {model.f1:.4f} (fp {model.fp}, fn {model.fn}) | "
            f"copy-last F1 {copy.f1:.4f} (fp {copy.fp}, fn {copy.fn})"
        )
    last = np.arange(bounds[-2], bounds[-1])
    false_positive = ((probability[last] >= THRESHOLD) & ~occupied[last + 1]).sum(axis=0)
    print(f"cells with the most false positives in frames {last[0]}-{last[-1]}:")
    for flat in np.argsort(false_positive.ravel())[::-1][: args.top]:
        row, col = divmod(int(flat), occupied.shape[2])
        before = occupied[10 : last[0], row, col].mean()
        during = occupied[last[0] :, row, col].mean()
        print(
            f"  row {row} col {col}: {int(false_positive[row, col])} false positives, "
            f"occupied {before:.0%} of the frames before, {during:.0%} during"
        )


if __name__ == "__main__":
    main()
