"""Would the last map *as it is* help the online combination as a ninth candidate?

The combination's ``copy_last`` expert is the last map moved into the sensor frame K guessed
steps on; the baseline it is judged against is the last map unmoved. On a platform that follows
a person, or whose scan matching jitters, the unmoved one can be the better mover prediction
(``general_tracking_moving_1`` and ``positive_4`` about one second ahead). Per captured fold
(:class:`studies.combination_ceiling.Capture`) and horizon, this scores:

- **hindsight**: the best pair with the unmoved last map deciding the rest of the cells (on
  either split), any candidate the common ones: what the ninth candidate could give at best;
- **replayed**: the combination's leader replayed over the kept candidates with and without
  the ninth (:meth:`Capture.replay`, both splits): what it gives when chosen online.

    PYTHONPATH=src:. python -m studies.still_candidate runs/ceiling/s0 runs/ceiling/s1

Writes OUT/summary.{json,md}: per seed, fold and horizon every column's margins.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from lidarflow.online.combination import CANDIDATES
from studies.combination_ceiling import SPLITS, Capture, margins_text, weighed
from studies.harness import parse, parser, write_summary


def still_maps(fold: Capture) -> np.ndarray:
    """The ninth candidate for every frame ``(frames, 1, H, W)``: the frame's own map, as the
    prediction of any frame ahead."""
    return fold.occupied[:, None]


def hindsight(fold: Capture, at: int) -> dict[str, Any]:
    """Per split, the best pair (by the leader's weighing) with the unmoved last map deciding
    the rest: ``{split: {"common": name, "margins": [...]}}``."""
    still = fold.methods["copy_last"][:, at]  # the baseline: the last map unmoved, decided
    masks = {"rare": fold.rare[:, at], "region": fold.causal_region}
    out = {}
    for split in SPLITS:
        margins = np.array(
            [fold.margins(np.where(masks[split], still, fold.candidates[:, at, a]), at)
             for a in range(len(CANDIDATES))]
        )  # fmt: skip
        best = int(np.argmax(weighed(margins)))
        out[split] = {"common": CANDIDATES[best], "margins": margins[best].tolist()}
    return out


def fold_rows(fold: Capture, at: int) -> dict[str, Any]:
    """The combination as it ran, the hindsight pairs and the replays with and without."""
    row: dict[str, Any] = {
        "model_combined": fold.margins(fold.methods["model_combined"][:, at], at).tolist(),
        "hindsight": hindsight(fold, at),
    }
    extra = still_maps(fold)
    for split in SPLITS:
        for name, more in (("replay", None), ("replay_still", extra)):
            row[f"{name}_{split}"] = fold.margins(fold.replay(at, split, more), at).tolist()
    return row


def markdown(seeds: list[dict[str, Any]]) -> str:
    """Per fold and horizon, the mean over seeds of each column's margins (all-cell / changed /
    tolerant mover), the hindsight pairs' common candidate beside them; then per column the mean,
    the worst fold and the folds won."""
    columns = ["model_combined"] + [f"{n}_{s}" for s in SPLITS for n in ("replay", "replay_still")]
    head = "| fold | at | " + " | ".join(columns) + " | hindsight_rare | hindsight_region |"
    lines = [head, "|---" * (len(columns) + 4) + "|"]
    for key in seeds[0]:
        name, at = key.split("@")
        cells = [margins_text(np.mean([s[key][c] for s in seeds], axis=0)) for c in columns]
        for split in SPLITS:
            m = np.mean([s[key]["hindsight"][split]["margins"] for s in seeds], axis=0)
            commons = "/".join(sorted({s[key]["hindsight"][split]["common"] for s in seeds}))
            cells.append(f"{margins_text(m)} ({commons})")
        lines.append(f"| {name} | {'k=1' if at == '0' else '~1 s'} | " + " | ".join(cells) + " |")
    lines += ["", "| column | at | mean margins | worst fold | folds won |", "|---" * 5 + "|"]
    for at in ("0", "1"):
        keys = [k for k in seeds[0] if k.endswith("@" + at)]
        for c in columns + [f"hindsight_{s}" for s in SPLITS]:
            def margins(row: dict[str, Any], c: str = c) -> Any:
                return row[c] if c in row else row["hindsight"][c[10:]]["margins"]

            m = np.array([np.mean([margins(s[k]) for s in seeds], axis=0) for k in keys])
            won = int((m > 0).all(axis=1).sum())
            when = "k=1" if at == "0" else "~1 s"
            lines.append(f"| {c} | {when} | {margins_text(m.mean(0))} | {margins_text(m.min(0))} | "
                         f"{won}/{len(m)} |")  # fmt: skip
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> list[dict[str, Any]]:
    p = parser("still_candidate", __doc__)
    p.add_argument("dirs", nargs="+", type=Path, help="captures, one folder per training seed")
    args = parse(p, argv)
    seeds = []
    for folder in args.dirs:
        seeds.append({
            f"{path.stem}@{at}": fold_rows(Capture(path), at)
            for path in sorted(folder.glob("*.npz")) for at in (0, 1)
        })  # fmt: skip
        print(f"{folder}: scored", flush=True)
    write_summary(args, "summary", seeds, markdown(seeds))
    return seeds


if __name__ == "__main__":
    main()
