"""Would a model's verdicts hold against other settings of the temporal average? (issue 11)

Reads `lidarflow evaluate` reports (JSON, one recording each, the model named ``--method``) and
the grid of temporal-average scores that ``studies.ta_sweep`` wrote, and judges the
model's F1 / changed-cell F1 in each file against copy-last, constant velocity and each named
temporal-average setting, by the verdict's rule (F1 above the best baseline's, changed-cell F1
above every baseline's). The model's decisions stay those of the file: with its online decision,
steered against the temporal average the evaluation was run with.

    python -m studies.ta_verdicts runs/s10/loo_ta3/eval_*.json \\
        --sweep runs/studies/ta_sweep/ta_sweep.json --settings 3/0.4 5/0.4 20/0.2

Writes OUT/ta_verdicts.json (per recording and setting: the F1 and changed-cell F1 margins)
and OUT/ta_verdicts.md.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

from studies.harness import parse, parser, read_json, stem, write_summary


def margins(model: dict, baselines: list[tuple[float, float]]) -> tuple[float, float]:
    """The model's F1 and changed-cell F1 margins over the best of ``(f1, changed_f1)`` pairs."""
    best_f1 = max(f1 for f1, _ in baselines)
    best_changed = max(changed for _, changed in baselines)
    return model["f1"] - best_f1, model["changed_f1"] - best_changed


def markdown(table: dict[str, dict[str, list[float]]], settings: list[str]) -> str:
    lines = ["| recording | " + " | ".join(settings) + " |", "|---" * (len(settings) + 1) + "|"]
    for name, row in table.items():
        cells = [
            f"{a:+.4f} / {b:+.4f}" + (" wins" if a > 0 and b > 0 else " **loses**")
            for a, b in row.values()
        ]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    wins = [sum(a > 0 and b > 0 for a, b in (row[s] for row in table.values())) for s in settings]
    lines.append("| wins | " + " | ".join(f"{w} of {len(table)}" for w in wins) + " |")
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> dict[str, dict[str, list[float]]]:
    p = parser("ta_verdicts", __doc__)
    p.add_argument("evaluations", type=Path, nargs="+", help="`lidarflow evaluate` reports (JSON)")
    p.add_argument("--sweep", type=Path, required=True, help="studies.ta_sweep's JSON")
    p.add_argument("--settings", nargs="+", default=["3/0.4", "5/0.4"])
    p.add_argument("--method", default="run", help="the model's name in the evaluations")
    args = parse(p, argv)
    written = read_json(args.sweep)
    # studies.ta_sweep's file holds the grid under "results"; older sweeps are the grid itself
    sweep = written.get("results", written)
    table: dict[str, dict[str, list[float]]] = {}
    for path in args.evaluations:
        entry = read_json(path)["recordings"][0]
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
    write_summary(args, "ta_verdicts", table, markdown(table, args.settings))
    return table


if __name__ == "__main__":
    main()
