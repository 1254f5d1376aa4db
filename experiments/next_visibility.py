"""Would knowing the next scan's shadows win positive_4? (issue 11)

Two thirds of the cells that change on the static recordings vanish into, or appear from, a cell
that is not visible in the other map. If what hides them were something the model could see
coming (a person stepping in front of a wall), ray-casting the predicted map would tell which
cells the next scan cannot see, and those cells cannot be occupied in it.

Three measurements on one recording and a model that never trained on it, each the best pair of
thresholds (cells occupied now / free now) in hindsight, as `history_rule.py --causal` reports:

- the model's probability alone;
- an oracle: the probability set to 0 where the *true* next visibility ``V^{t+1}`` says hidden
  (an upper bound, not a method: ``V^{t+1}`` arrives with the map it predicts);
- causal: set to 0 where the model's own predicted map (probability >= ``--cast``), ray-cast
  from the sensor, newly hides a cell (hidden behind the predicted map, not behind ``O^t``);
  with how many of the cells that truly vanish into a new shadow it catches.

    python experiments/next_visibility.py ../shared/data/positive_4.bag \\
        -m runs/loo/subcell_p4/head_subcell/positive_4/run --json next_visibility.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from history_rule import (
    WARMUP,
    _best_pair,
    _counts_by_class,
    best_baselines,
    model_probabilities,
)

from lidarflow.data import load_any
from lidarflow.scan import GridSpec

BEARING_BINS = 2048
FAR = 0.3


class ShadowCaster:
    """Cells strictly behind an occupied cell, seen from the sensor (the middle of the grid's
    bottom edge). Cells are squares: each covers the bearings of its half-width; a cell is
    hidden when the nearest occupied cell at its centre's bearing is more than half a cell
    nearer. Cruder than a scan (a wall at a grazing angle hides its own far cells), so only
    differences between two maps' shadows are used."""

    def __init__(self, grid: GridSpec) -> None:
        h, w, res = grid.height, grid.width, grid.res
        rows, cols = np.mgrid[0:h, 0:w]
        x, y = (h - rows - 0.5) * res, (w / 2 - cols - 0.5) * res
        self.distance = np.hypot(x, y).ravel()
        bearing = np.arctan2(y, x).ravel()
        half = np.arctan2(0.5 * res, self.distance)
        first, last = self._bin(bearing - half), self._bin(bearing + half)
        self.cell = np.repeat(np.arange(h * w), last - first + 1)
        self.bin = np.concatenate([np.arange(a, b + 1) for a, b in zip(first, last, strict=True)])
        self.centre_bin = self._bin(bearing)
        self.shape, self.margin = (h, w), 0.5 * res

    @staticmethod
    def _bin(angle: np.ndarray) -> np.ndarray:
        return np.clip(
            ((angle + np.pi) / (2 * np.pi) * BEARING_BINS).astype(int), 0, BEARING_BINS - 1
        )

    def __call__(self, occupied: np.ndarray) -> np.ndarray:
        return self.depth(occupied) > self.margin

    def depth(self, occupied: np.ndarray) -> np.ndarray:
        """``(H, W)`` metres each cell lies behind the nearest occupied cell at its bearing
        (negative in front of it, -inf where nothing is occupied at that bearing)."""
        near = np.where(occupied.ravel()[self.cell], self.distance[self.cell], np.inf)
        first_hit = np.full(BEARING_BINS, np.inf)
        np.minimum.at(first_hit, self.bin, near)
        return (self.distance - first_hit[self.centre_bin]).reshape(self.shape)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recording", type=Path)
    parser.add_argument(
        "-m", "--model", type=Path, required=True, help="a model never trained on it"
    )
    parser.add_argument("--cast", type=float, nargs="+", default=[0.3, 0.4, 0.5, 0.6])
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    recording = load_any(args.recording)
    grid = GridSpec()
    occupancy, visibility = recording.maps(grid)
    probability = model_probabilities(args.model, recording, (occupancy, visibility))
    best = best_baselines(occupancy, visibility)
    occupied, visible = occupancy.astype(bool), visibility.astype(bool)
    t = np.arange(WARMUP, len(occupied) - 1)
    current, target, p = occupied[t], occupied[t + 1], probability[t]
    vanished = current & ~target
    newly_hidden = vanished & visible[t] & ~visible[t + 1]

    def best_pair(prob: np.ndarray) -> dict:
        return _best_pair(_counts_by_class(prob, current, target), best)

    shadow = ShadowCaster(grid)
    # How far in front of a vanished cell the next scan's nearest return lies: a few
    # centimetres is the surface's own return jittering nearer, more is something in between.
    depth_next = np.stack([shadow.depth(occupied[i + 1]) for i in t])
    behind = depth_next[newly_hidden]
    # What a perfect predictor of people's next places could know: the shadows that something
    # at least FAR metres in front of a cell casts on it (not the surface's own jitter).
    far_shadow = ~visible[t + 1] & visible[t] & (depth_next >= FAR)
    out: dict = {
        "recording": args.recording.name,
        "best_baselines": best,
        "vanished": int(vanished.sum()),
        "vanished_into_a_new_shadow": int(newly_hidden.sum()),
        "vanished_into_a_new_shadow_within_m": {
            str(m): int((behind <= m).sum()) for m in (0.0, 0.15, 0.3, 0.5, 1.0, 3.0, 10.0)
        },
        "model": best_pair(p),
        "oracle_next_visibility": best_pair(p * visible[t + 1]),
        f"oracle_shadows_cast_from_{FAR}_m_or_more": best_pair(p * ~far_shadow),
    }
    now = np.stack([shadow(m) for m in current])
    for cast in args.cast:
        new = np.stack([shadow(m) for m in p >= cast]) & ~now
        out[f"predicted_shadow_cast_{cast}"] = best_pair(p * ~new) | {
            "new_shadow_cells": int(new.sum()),
            "catches_vanished": int((new & vanished).sum()),
            "hides_cells_that_stay": int((new & current & target).sum()),
        }
    for name, row in out.items():
        print(f"{name}: {row}")
    if args.json:
        args.json.write_text(json.dumps(out, indent=2) + "\n")


if __name__ == "__main__":
    main()
