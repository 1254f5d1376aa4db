"""Which other per-cell facts sharpen a cell's history? A screen for positive_4 (issue 11).

The sub-cell bits (where the returns lie inside their cells) took the causal history table of
``history_rule.py --causal --subcell`` on positive_4 from -0.0171 to -0.0114, and the model
with them from -0.0183 to -0.0135 (docs/results/accuracy/positive_4/subcell/). This keys that
table (the last K values and the two sub-cell bits) by one more fact per cell and frame, each a
guess at why a static scene's cells change, and scores it the same way (the other recordings'
table as a prior weighted by ``--prior``, updated by the held-out stream once each next map has
arrived; the best threshold pair in hindsight; margin over the best baselines):

- ``count``: how many returns fell in the cell (0, 1, 2-3, 4+): a cell hit by one beam loses it
  more easily than one hit by five.
- ``spacing``: the gap between neighbouring beams at the cell's distance, in cells (< 0.2,
  0.2-0.5, more): where beams are sparse, walls alias between cells.
- ``submem``: the sub-cell bits of any of the last three frames, not only this one.
- ``neigh``: occupied 4-neighbours now (0-3+).
- ``vis``: the cell is visible now.
- ``jitterD`` (D in cm): along-beam jitter, for every beam the cells its return would fall in
  at range +-D: the cell's own returns could leave it; a return from elsewhere would land here
  at +D (behind a surface); at -D (in front).
- ``markovD`` (D a decay, 1 for none): the cell's own causal rate of changing from the state it
  is in now, from its past transitions (6 bins): a per-cell two-state Markov chain.

``--in-sample`` fits each recording's table on itself instead (an optimistic bound: keys seen
a few times are memorised), and ``--split`` asks whether a recording's own past predicts its
future better than the other recordings do: the second half predicted by the table of its first
half, by the others', and by the whole recording in-sample.

    python experiments/history_keys.py --keys none count spacing submem neigh vis jitter2.5 \\
        jitter5 markov1 markov0.98 --json docs/results/accuracy/positive_4/history_keys.json
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
from history_rule import (
    PAIR_THRESHOLDS,
    WARMUP,
    _best_pair,
    _counts_by_class,
    best_baselines,
    table_codes,
    table_size,
)

from lidarflow.data import Recording, load_any
from lidarflow.scan import GridSpec

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
STATIC = ("positive_1", "positive_2", "positive_3", "positive_4",
          "demo_stationary_simple_environment")  # fmt: skip
GRID = GridSpec()


def _beam_cells(ranges: np.ndarray, recording: Recording, i: int) -> np.ndarray:
    """Flat grid index of each beam's point at ``ranges`` (``-1``: no return, or off the grid),
    with ``rasterize_batch``'s arithmetic."""
    angles = recording.geometry(i).angles
    with np.errstate(invalid="ignore"):
        u = GRID.height - ranges * np.cos(angles) / GRID.res
        v = GRID.width / 2 - ranges * np.sin(angles) / GRID.res
        row, col = np.floor(u), np.floor(v)
        ok = np.isfinite(ranges) & (row >= 0) & (row < GRID.height) & (col >= 0)
        ok &= col < GRID.width
    return np.where(ok, row * GRID.width + col, -1).astype(np.int64)


def _returns(recording: Recording, i: int) -> np.ndarray:
    g, r = recording.geometry(i), np.asarray(recording.scan(i).ranges, np.float64)
    with np.errstate(invalid="ignore"):
        return np.where((r >= g.range_min) & (r <= g.range_max), r, np.nan)


def return_counts(recording: Recording) -> np.ndarray:
    out = np.zeros((len(recording), GRID.height * GRID.width), np.int64)
    for i in range(len(recording)):
        cells = _beam_cells(_returns(recording, i), recording, i)
        np.add.at(out[i], cells[cells >= 0], 1)
    return out.reshape(len(recording), *GRID.shape)


def beam_spacing(recording: Recording) -> np.ndarray:
    rows, cols = np.mgrid[0 : GRID.height, 0 : GRID.width]
    x, y = (GRID.height - rows - 0.5) * GRID.res, (GRID.width / 2 - cols - 0.5) * GRID.res
    cells_away = np.hypot(x, y) / GRID.res
    out = np.empty((len(recording), *GRID.shape))
    for i in range(len(recording)):
        out[i] = cells_away * abs(recording.geometry(i).angle_increment)
    return out


def jitter_bits(recording: Recording, delta: float) -> np.ndarray:
    """``4 * own returns could leave + 2 * one would land here at +delta + 1 * at -delta``."""
    out = np.zeros((len(recording), GRID.height * GRID.width), np.int64)
    for i in range(len(recording)):
        r = _returns(recording, i)
        here = _beam_cells(r, recording, i)
        beyond, before = _beam_cells(r + delta, recording, i), _beam_cells(r - delta, recording, i)
        hit = here >= 0
        stays = np.zeros(out.shape[1], bool)
        stays[here[hit & (beyond == here) & (before == here)]] = True
        occupied = np.zeros(out.shape[1], bool)
        occupied[here[hit]] = True
        out[i] += 4 * (occupied & ~stays)
        for bit, moved in ((2, beyond), (1, before)):
            lands = np.zeros(out.shape[1], bool)
            lands[moved[hit & (moved >= 0) & (moved != here)]] = True
            out[i] += bit * lands
    return out.reshape(len(recording), *GRID.shape)


def markov_rates(occupancy: np.ndarray, decay: float) -> np.ndarray:
    """Per cell and frame, causal: the rate at which the cell has left the state it is in now
    (transitions up to this frame, decayed by ``decay``; a weak prior of 0.5)."""
    o = occupancy.astype(bool)
    moves, stays = np.zeros((2, *o.shape[1:])), np.zeros((2, *o.shape[1:]))
    out = np.empty(o.shape)
    for t in range(len(o)):
        if t:
            moves *= decay
            stays *= decay
            for state in (0, 1):
                was = o[t - 1] == bool(state)
                moves[state][was & (o[t] != o[t - 1])] += 1
                stays[state][was & (o[t] == o[t - 1])] += 1
        state = o[t].astype(np.intp)[None]
        m, s = np.take_along_axis(moves, state, 0)[0], np.take_along_axis(stays, state, 0)[0]
        out[t] = (m + 0.025) / (m + s + 0.05)
    return out


def key(kind: str, recording: Recording, occupancy: np.ndarray, visibility: np.ndarray,
        subcell: np.ndarray) -> tuple[np.ndarray, int]:  # fmt: skip
    """The extra key ``(N, H, W)`` of ``kind`` (see the module's docstring) and its levels."""
    if kind == "none":
        return np.zeros(occupancy.shape, np.int64), 1
    if kind == "count":
        return np.digitize(return_counts(recording), [1, 2, 4]), 4
    if kind == "spacing":
        return np.digitize(beam_spacing(recording), [0.2, 0.5]), 3
    if kind == "submem":
        bits = subcell.astype(np.int64)
        seen = np.zeros_like(bits)
        for lag in (1, 2, 3):
            seen[lag:] |= bits[:-lag]
        return 2 * seen[:, 1] + seen[:, 0], 4
    if kind == "neigh":
        o = np.pad(occupancy.astype(np.int64), ((0, 0), (1, 1), (1, 1)))
        n4 = o[:, :-2, 1:-1] + o[:, 2:, 1:-1] + o[:, 1:-1, :-2] + o[:, 1:-1, 2:]
        return np.minimum(n4, 3), 4
    if kind == "vis":
        return visibility.astype(np.int64), 2
    if kind.startswith("jitter"):
        return jitter_bits(recording, float(kind[len("jitter") :]) / 100), 8
    if kind.startswith("markov"):
        rates = markov_rates(occupancy, float(kind[len("markov") :]))
        return np.digitize(rates, [0.02, 0.05, 0.1, 0.2, 0.4]), 6
    raise SystemExit(f"unknown key {kind!r}")


class Keyed:
    """One recording's table codes (last ``k`` values, sub-cell bits, the extra key) and targets."""

    def __init__(self, recording: Recording, kind: str, k: int) -> None:
        self.occupancy, self.visibility = recording.maps(GRID)
        subcell = recording.subcell_maps(GRID)
        extra, self.levels = key(kind, recording, self.occupancy, self.visibility, subcell)
        code, self.target = table_codes(self.occupancy, k, None, subcell)
        self.code = code * self.levels + extra[k - 1 : -1]  # code i: frames i .. i+k-1 -> i+k
        self.k = k
        self.size = table_size(k, False, True) * self.levels

    def frames(self, start: int, stop: int) -> range:
        """Code indices of the scored frames ``start <= t < stop`` (``t`` the current frame)."""
        return range(max(start, WARMUP) - (self.k - 1), stop - (self.k - 1))

    def margin(self, counts: np.ndarray, start: int = 0, stop: int | None = None) -> float:
        stop = len(self.occupancy) - 1 if stop is None else stop
        lo = max(start, WARMUP) - WARMUP  # the baselines warm up on the ten frames before
        best = best_baselines(self.occupancy[lo : stop + 1], self.visibility[lo : stop + 1])
        return float(_best_pair(counts, best)["margin"])

    def counts(self, i: int, probability: np.ndarray) -> np.ndarray:
        current = self.occupancy[i + self.k - 1].ravel() > 0
        return _counts_by_class(probability[self.code[i]].ravel(), current, self.target[i].ravel())


def table(parts: list[tuple[Keyed, range]], size: int) -> tuple[np.ndarray, np.ndarray]:
    ones, total = np.zeros(size), np.zeros(size)
    for keyed, frames in parts:
        part = slice(frames.start, frames.stop)
        code, target = keyed.code[part], keyed.target[part]
        np.add.at(total, code.ravel(), 1)
        np.add.at(ones, code.ravel(), target.ravel())
    return ones, total


def rate(ones: np.ndarray, total: np.ndarray) -> np.ndarray:
    return ones / np.maximum(total, 1e-12)


def causal(keyed: dict[str, Keyed], name: str, prior: float) -> float:
    held = keyed[name]
    others = [(k, range(len(k.code))) for n, k in keyed.items() if n != name]
    ones, total = table(others, held.size)
    ones, total = prior * ones, prior * total
    counts = np.zeros((2, len(PAIR_THRESHOLDS), 2, 3))
    for i in range(len(held.code)):
        if i + held.k - 1 >= WARMUP:
            counts += held.counts(i, rate(ones, total))
        np.add.at(total, held.code[i].ravel(), 1)  # its next map has arrived: learn from it
        np.add.at(ones, held.code[i].ravel(), held.target[i].ravel())
    return held.margin(counts)


def in_sample(keyed: dict[str, Keyed], name: str, start: int = 0) -> float:
    held = keyed[name]
    p = rate(*table([(held, range(len(held.code)))], held.size))
    frames = held.frames(start, len(held.occupancy) - 1)
    return held.margin(sum(held.counts(i, p) for i in frames), start)


def split(keyed: dict[str, Keyed], name: str, prior: float) -> dict[str, float]:
    held = keyed[name]
    middle, end = len(held.occupancy) // 2, len(held.occupancy) - 1
    first = table([(held, held.frames(0, middle))], held.size)
    others = table([(k, range(len(k.code))) for n, k in keyed.items() if n != name], held.size)
    second = held.frames(middle, end)

    def score(p: np.ndarray) -> float:
        return held.margin(sum(held.counts(i, p) for i in second), middle)

    mixed = (first[0] + prior * others[0], first[1] + prior * others[1])
    return {
        "others": score(rate(*others)),
        "own_first_half": score(np.where(first[1] > 0, rate(*first), rate(*others))),
        f"own_first_half_plus_others_x{prior}": score(rate(*mixed)),
        "in_sample": in_sample(keyed, name, middle),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--recordings", type=Path, nargs="+",
                        default=[DATA / f"{n}.bag" for n in STATIC])  # fmt: skip
    parser.add_argument("--keys", nargs="+", default=["none", "count"])
    parser.add_argument("--k", type=int, default=8)
    parser.add_argument("--prior", type=float, default=0.3)
    parser.add_argument("--in-sample", action="store_true")
    parser.add_argument("--split", action="store_true")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    recordings = {p.name.split(".")[0]: load_any(p) for p in args.recordings}
    mode = "split" if args.split else "in_sample" if args.in_sample else "causal"
    run: Callable[[dict[str, Keyed], str], object] = {
        "causal": lambda keyed, name: causal(keyed, name, args.prior),
        "in_sample": in_sample,
        "split": lambda keyed, name: split(keyed, name, args.prior),
    }[mode]
    results: dict[str, dict[str, object]] = {}
    for kind in args.keys:
        keyed = {name: Keyed(r, kind, args.k) for name, r in recordings.items()}
        results[kind] = {name: run(keyed, name) for name in keyed}
        print(kind, json.dumps(results[kind]), flush=True)
    if args.json:
        payload = {"mode": mode, "k": args.k, "prior": args.prior, "warmup": WARMUP,
                   "subcell": True, "recordings": [str(p) for p in args.recordings],
                   "margins": results}  # fmt: skip
        args.json.write_text(json.dumps(payload, indent=2) + "\n")


if __name__ == "__main__":
    main()
