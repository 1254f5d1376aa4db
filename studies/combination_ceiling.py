"""How far can the online combination's choice go with the experts it has?

Per development fold (its model held out), the combination streams the recording as `evaluate
--horizon K` does; every frame, each candidate's decided map 1 and K ahead is kept
(``capture``: :mod:`studies.combination_capture`). Offline (``table``), each fixed choice of
two candidates, one deciding the common cells and one the rest, is scored with the horizon
tables' metric: on the combination's own split (the tracker's rare cells) and on the cells
where movers went so far (its causal mover region). Three choices are compared with the
combination as it ran:

- **in hindsight**: the pair best on the recording itself (an optimistic ceiling: it is chosen
  on the frames it is scored on);
- **left out**: the pair best on the six other recordings (the mean of their margins, losses
  weighed ten times, as the leader weighs them), scored on the held-out one;
- **online**: what the combination decided, learning on the stream; and its leader replayed
  over the kept candidates with either split (:meth:`Capture.replay`).

Writes OUT/<recording>.npz per recording (kept ones are not captured again); ``table`` and
``halves`` cache their scores beside them (``pairs.json``, ``replays.json``, ``halves.json``)
and write ``ceiling.json`` or ``warm.json`` beside the seeds' folders.

``halves`` asks what a chooser that has already seen a robot's recording could do: the pair
best on the first half of a recording, scored on the second half, beside the model and the
combination on the second half (all judged against the baselines on the second half).

    PYTHONPATH=src:. python -m studies.combination_ceiling capture -o runs/ceiling/s0 \
        --fold-runs runs/movers/s0
    PYTHONPATH=src:. python -m studies.combination_ceiling table runs/ceiling/s0 runs/ceiling/s1
    PYTHONPATH=src:. python -m studies.combination_ceiling halves runs/ceiling/s0 runs/ceiling/s1
"""

from __future__ import annotations

import copy
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from lidarflow.evaluate.metrics import confusion
from lidarflow.evaluate.movers import TolerantCounts
from lidarflow.online.combination import CANDIDATES
from lidarflow.online.leader import LOSS_WEIGHT, Arrived, Leader
from lidarflow.scan import GridSpec
from studies.combination_capture import capture
from studies.harness import development, parse, parser, read_json, stem, write_json
from studies.online_combination import BASELINES

#: The splits of the cells a pair is chosen for: the combination's own, and the region.
SPLITS = ("rare", "region")


class Capture:
    """A captured fold, unpacked: the frames scored, the truths, the regions."""

    def __init__(self, path: Path) -> None:
        z = np.load(path)
        self.path, self.name, self.horizon = path, path.stem, int(z["horizon"])
        bits = _unpacked
        self.scored = z["scored"]
        self.occupied, self.region = bits(z["occupied"]), bits(z["region"])
        self.candidates = bits(z["candidates"])[self.scored]  # (T, 2, C, H, W)
        self.rare = bits(z["rare"])[self.scored]  # (T, 2, H, W)
        self.causal_region = bits(z["causal_region"])[self.scored]  # (T, H, W)
        self.methods = {k[7:]: bits(z[k]) for k in z.files if k.startswith("method/")}

    def half(self, which: int) -> Capture:
        """The same capture, its scored frames cut to the first (``which`` 0) or the second
        half."""
        cut = len(self.scored) // 2
        part = slice(None, cut) if which == 0 else slice(cut, None)
        out = copy.copy(self)
        out.scored, out.candidates = self.scored[part], self.candidates[part]
        out.rare, out.causal_region = self.rare[part], self.causal_region[part]
        out.methods = {name: maps[part] for name, maps in self.methods.items()}
        return out

    def metrics(self, decided: np.ndarray, at: int) -> np.ndarray:
        """F1, changed-cell F1 and tolerant mover F1 of ``decided`` ``(T, H, W)`` for the
        frames 1 (``at`` 0) or K (``at`` 1) ahead of the scored ones, as the horizon tables
        count them (summed over the frames)."""
        k = 1 if at == 0 else self.horizon
        truth, before = self.occupied[self.scored + k], self.occupied[self.scored]
        region = self.region[self.scored + k]
        changed = before != truth
        # the horizon tables' own counts, summed over the frames at once
        return np.array(
            [
                confusion(decided, truth).f1,
                confusion(decided, truth, changed).f1,
                TolerantCounts.of(decided, truth, region).f1,
            ]
        )

    def margins(self, decided: np.ndarray, at: int) -> np.ndarray:
        """As the study judges: F1 and changed-cell F1 over the best baseline, tolerant mover
        F1 over copy-last."""
        base = {b: self.metrics(self.methods[b][:, at], at) for b in BASELINES if b in self.methods}
        best = np.max(list(base.values()), axis=0)
        got = self.metrics(decided, at)
        return np.array([got[0] - best[0], got[1] - best[1], got[2] - base["copy_last"][2]])

    def replay(self, at: int, split: str, extra: np.ndarray | None = None) -> np.ndarray:
        """The combination's leader replayed over every frame's kept candidates (and ``extra``
        ones ``(frames, E, H, W)`` bool after them), deciding the cells ``split``
        (:data:`SPLITS`) apart: its decided maps of the scored frames ``(T, H, W)``. The
        candidates it scores are those output (the experts' maps decided as they are, not as
        kept in eight bits), so the rare split is close to, not the same as, the combination
        as it ran."""
        z = np.load(self.path)
        candidates = _unpacked(z["candidates"])[:, at]
        if extra is not None:
            candidates = np.concatenate([candidates, extra[: len(candidates)]], axis=1)
        masks = _unpacked(z["rare"])[:, at] if split == "rare" else _unpacked(z["causal_region"])
        region = _unpacked(z["causal_region"])
        k = 1 if at == 0 else self.horizon
        simple = tuple(CANDIDATES.index(n) for n in ("copy_last", "temporal_average", "tracker"))
        leader = Leader(candidates.shape[1], CANDIDATES.index("model"), baselines=simple)
        out = np.empty(candidates.shape[:1] + candidates.shape[2:], bool)
        for t in range(len(candidates)):
            if t >= k:  # frame t labels what was predicted k frames before
                past = t - k
                arrived = Arrived(self.occupied[t], region[t])
                leader.score(candidates[past], masks[past], self.occupied[past], arrived)
            a, b = leader.choice
            out[t] = np.where(masks[t], candidates[t, b], candidates[t, a])
        return out[self.scored]

    def pairs(self, at: int) -> dict[str, np.ndarray]:
        """Every fixed pair's margins ``(C, C, 3)`` (common, rest) per split."""
        c = self.candidates[:, at]
        splits = {"rare": self.rare[:, at], "region": self.causal_region}
        out = {}
        for split, mask in splits.items():
            grid = np.empty((len(CANDIDATES), len(CANDIDATES), 3))
            for a in range(len(CANDIDATES)):
                for b in range(len(CANDIDATES)):
                    grid[a, b] = self.margins(np.where(mask, c[:, b], c[:, a]), at)
            out[split] = grid
        return out


def _unpacked(a: np.ndarray) -> np.ndarray:
    """Bit-packed maps of the study's grid (:class:`GridSpec`'s default) as bool."""
    return np.unpackbits(a, axis=-1, count=GridSpec().width).astype(bool)


def weighed(margins: np.ndarray) -> np.ndarray:
    """The leader's score of margins ``(..., 3)``: their sum, each loss weighing
    :data:`LOSS_WEIGHT` times more."""
    return (margins + LOSS_WEIGHT * np.minimum(margins, 0.0)).sum(axis=-1)


def _cached(path: Path, compute: Callable[[], dict[str, Any]]) -> dict[str, Any]:
    """``path``'s JSON where it exists, else ``compute()`` written there."""
    if path.exists():
        return read_json(path)
    out = compute()
    write_json(path, out)
    return out


def _scores(fold: Capture, at: int) -> dict[str, Any]:
    """The model's, the online combination's and every fixed pair's margins at ``at``."""
    names = ("model", "model_combined")
    out = {name: fold.margins(fold.methods[name][:, at], at).tolist() for name in names}
    return {**out, **{split: grid.tolist() for split, grid in fold.pairs(at).items()}}


def summarise(folder: Path) -> dict[str, Any]:
    """Per captured fold in ``folder`` and horizon (``"0"``: 1 ahead, ``"1"``: K): the model's,
    the online combination's and every fixed pair's margins (cached in ``folder/pairs.json``)."""

    def compute() -> dict[str, Any]:
        out: dict[str, Any] = {}
        for path in sorted(folder.glob("*.npz")):
            fold = Capture(path)
            for at in (0, 1):
                out.setdefault(fold.name, {})[str(at)] = {**_scores(fold, at), "K": fold.horizon}
                print(f"{fold.name} at {'1' if at == 0 else 'K'}: done", flush=True)
        return out

    return _cached(folder / "pairs.json", compute)


def summarise_replays(folder: Path) -> dict[str, Any]:
    """Per captured fold and horizon, the margins of the leader replayed with each split
    (:meth:`Capture.replay`; cached in ``folder/replays.json``)."""

    def compute() -> dict[str, Any]:
        out: dict[str, Any] = {}
        for path in sorted(folder.glob("*.npz")):
            fold = Capture(path)
            for at in (0, 1):
                out.setdefault(fold.name, {})[str(at)] = {
                    f"replay_{split}": fold.margins(fold.replay(at, split), at).tolist()
                    for split in SPLITS
                }
        return out

    return _cached(folder / "replays.json", compute)


def summarise_halves(folder: Path) -> dict[str, Any]:
    """:func:`summarise` on each half of every captured recording apart (``folder/halves.json``):
    ``{fold: {at: {"first": ..., "second": ...}}}``."""

    def compute() -> dict[str, Any]:
        out: dict[str, Any] = {}
        for path in sorted(folder.glob("*.npz")):
            whole = Capture(path)
            for at in (0, 1):
                halves = {n: _scores(whole.half(i), at) for i, n in enumerate(("first", "second"))}
                out.setdefault(whole.name, {})[str(at)] = halves
                print(f"{whole.name} halves at {'1' if at == 0 else 'K'}: done", flush=True)
        return out

    return _cached(folder / "halves.json", compute)


def warm(halves: list[dict[str, Any]]) -> dict[str, Any]:
    """Per fold and horizon, on the second half of each recording (mean over seeds): the
    model, the online combination, and the pair best on the first half (as a chooser that has
    seen the first half would take it)."""
    rows: dict[str, Any] = {}
    for fold in sorted(halves[0]):
        for at in ("0", "1"):
            row = rows.setdefault(f"{fold}@{at}", {})
            for name in ("model", "model_combined"):
                margins = np.mean([h[fold][at]["second"][name] for h in halves], axis=0)
                row[name] = {"margins": margins.tolist()}
            for split in SPLITS:
                first = np.mean([np.array(h[fold][at]["first"][split]) for h in halves], 0)
                second = np.mean([np.array(h[fold][at]["second"][split]) for h in halves], 0)
                a, b = np.unravel_index(np.argmax(weighed(first)), first.shape[:2])
                row[f"warm_{split}"] = {
                    "margins": second[a, b].tolist(),
                    "pair": [CANDIDATES[a], CANDIDATES[b]],
                }
    return rows


def chosen(seeds: list[dict[str, Any]]) -> dict[str, Any]:
    """Per fold and horizon, the margins (mean over seeds) of the model, the online
    combination, and the fixed pairs chosen in hindsight and left out, per split."""
    folds = sorted(seeds[0])
    rows: dict[str, Any] = {}
    for at in ("0", "1"):
        for split in SPLITS:
            grids = {f: np.mean([np.array(s[f][at][split]) for s in seeds], 0) for f in folds}
            for fold in folds:
                grid = grids[fold]
                hindsight = np.unravel_index(np.argmax(weighed(grid)), grid.shape[:2])
                choices = {"hindsight": hindsight}
                if len(folds) > 1:  # the pair best on the others
                    others = np.mean([weighed(grids[f]) for f in folds if f != fold], axis=0)
                    choices["left_out"] = np.unravel_index(np.argmax(others), others.shape)
                row = rows.setdefault(f"{fold}@{at}", {})
                for name, (a, b) in choices.items():
                    row[f"{name}_{split}"] = {
                        "margins": grid[a, b].tolist(),
                        "pair": [CANDIDATES[a], CANDIDATES[b]],
                    }
        for fold in folds:
            for name in ("model", "model_combined", *(f"replay_{s}" for s in SPLITS)):
                if name not in seeds[0][fold][at]:
                    continue
                margins = np.mean([s[fold][at][name] for s in seeds], axis=0)
                rows[f"{fold}@{at}"][name] = {"margins": margins.tolist()}
    return rows


def table(folders: list[Path], halves: bool = False) -> str:
    """Markdown: per fold and horizon, then aggregated, the margins of each choice (mean over
    the seeds' ``folders``); with ``halves``, on the second half of each recording
    (:func:`warm`). Writes ``ceiling.json`` (or ``warm.json``) beside the folders."""
    if halves:
        rows = warm([summarise_halves(f) for f in folders])
        columns = ["model", "model_combined", *(f"warm_{s}" for s in SPLITS)]
    else:
        seeds = [summarise(f) for f in folders]
        for seed, folder in zip(seeds, folders, strict=True):
            for fold, by_at in summarise_replays(folder).items():
                for at, replays in by_at.items():
                    seed[fold][at].update(replays)
        rows = chosen(seeds)
        fixed = [f"{n}_{s}" for n in ("replay", "left_out", "hindsight") for s in SPLITS]
        columns = ["model", "model_combined", *fixed]
    lines = ["| held-out | at | " + " | ".join(columns) + " |", "|---" * (len(columns) + 2) + "|"]
    for key, row in rows.items():
        fold, at = key.split("@")
        cells = [_cell(row[c]) if c in row else "-" for c in columns]
        lines.append(f"| {fold} | {'k=1' if at == '0' else '~1 s'} | " + " | ".join(cells) + " |")
    lines += ["", "| choice | at | mean margins | worst fold | folds won |", "|---" * 5 + "|"]
    for at in ("0", "1"):
        for c in columns:
            m = np.array([r[c]["margins"] for k, r in rows.items() if k.endswith(at) and c in r])
            if not len(m):
                continue
            won = int((m > 0).all(axis=1).sum())
            lines.append(
                f"| {c} | {'k=1' if at == '0' else '~1 s'} | {margins_text(m.mean(0))} | "
                f"{margins_text(m.min(0))} | {won}/{len(m)} |"
            )
    write_json(folders[0].parent / ("warm.json" if halves else "ceiling.json"), rows)
    return "\n".join(lines)


def _cell(entry: dict[str, Any]) -> str:
    pair = f" ({'/'.join(entry['pair'])})" if "pair" in entry else ""
    return margins_text(np.array(entry["margins"])) + pair


def margins_text(m: np.ndarray) -> str:
    """Margins ``(3,)`` as the tables print them: all-cell / changed / tolerant mover."""
    return f"{m[0]:+.4f} / {m[1]:+.3f} / {m[2]:+.3f}"


def main(argv: list[str] | None = None) -> None:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] in ("table", "halves"):
        print(table([Path(a) for a in argv[1:]], halves=argv[0] == "halves"))
        return
    if argv and argv[0] == "capture":
        argv = argv[1:]
    p = parser("combination_ceiling", __doc__)
    p.add_argument("--fold-runs", type=Path, required=True, help="FOLDER/<recording>/run models")
    p.add_argument("--recordings", nargs="*", type=Path, default=None)
    args = parse(p, argv)
    for path in args.recordings or development():
        target = args.output / f"{stem(path)}.npz"
        if not target.exists():
            capture(path, args.fold_runs / stem(path) / "run", target)
        print(f"{stem(path)}: captured", flush=True)


if __name__ == "__main__":
    main()
