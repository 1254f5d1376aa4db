"""Would a model's verdicts hold against other settings of the temporal average? (issue 11)

Reads `lidarflow evaluate --json` files (one recording each, the model named ``--method``) and
the grid of temporal-average scores that ``experiments/ta_sweep.py`` wrote, and judges the
model's F1 / changed-cell F1 in each file against copy-last, constant velocity and each named
temporal-average setting, by the verdict's rule (F1 above the best baseline's, changed-cell F1
above every baseline's). The model's decisions stay those of the file: with its online decision,
steered against the temporal average the evaluation was run with.

    python experiments/ta_verdicts.py runs/s10/loo_ta3/eval_*.json \\
        --sweep docs/results/accuracy/temporal_average/ta_sweep.json --settings 3/0.4 5/0.4 20/0.2
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def stem(path: str) -> str:
    name = Path(path).name
    for suffix in (".zip", ".bag", ".npz", ".mcap"):
        name = name.removesuffix(suffix)
    return name


def margins(model: dict, baselines: list[tuple[float, float]]) -> tuple[float, float]:
    """The model's F1 and changed-cell F1 margins over the best of ``(f1, changed_f1)`` pairs."""
    best_f1 = max(f1 for f1, _ in baselines)
    best_changed = max(changed for _, changed in baselines)
    return model["f1"] - best_f1, model["changed_f1"] - best_changed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("evaluations", type=Path, nargs="+")
    parser.add_argument("--sweep", type=Path, required=True)
    parser.add_argument("--settings", nargs="+", default=["3/0.4", "5/0.4"])
    parser.add_argument("--method", default="run")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    sweep = json.loads(args.sweep.read_text())
    table: dict[str, dict[str, list[float]]] = {}
    for path in args.evaluations:
        entry = json.loads(path.read_text())["recordings"][0]
        name, methods = stem(entry["path"]), entry["methods"]
        fixed = [
            (methods[b]["f1"], methods[b]["changed_f1"]) for b in ("copy_last", "constant_velocity")
        ]
        key = next((k for k in sweep if name.startswith(k) or k.startswith(name)), None)
        if key is None:
            print(f"{path}: {name} is not in {args.sweep}; left out", file=sys.stderr)
            continue
        table[name] = {}
        for setting in args.settings:
            f1_margin, changed_margin = margins(
                methods[args.method], [*fixed, tuple(sweep[key][setting])]
            )
            table[name][setting] = [f1_margin, changed_margin]
    print("| recording | " + " | ".join(args.settings) + " |")
    print("|---" * (len(args.settings) + 1) + "|")
    for name, row in table.items():
        cells = [
            f"{a:+.4f} / {b:+.4f}" + (" wins" if a > 0 and b > 0 else " **loses**")
            for a, b in row.values()
        ]
        print(f"| {name} | " + " | ".join(cells) + " |")
    wins = [
        sum(a > 0 and b > 0 for a, b in (row[s] for row in table.values())) for s in args.settings
    ]
    print("| wins | " + " | ".join(f"{w} of {len(table)}" for w in wins) + " |")
    if args.json:
        args.json.write_text(json.dumps(table, indent=1))


if __name__ == "__main__":
    main()
