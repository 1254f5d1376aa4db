"""The ablation table of models already trained, from `lidarflow evaluate --json` reports.

Where the models were trained elsewhere (the same training recordings, different recipes), this
turns their evaluations on recordings none of them trained on into the table that
`leave_one_out.py` writes: one row per model and recording, F1 / changed-cell F1 / AP beside the
best baselines, and the verdict ("wins" = F1 above the best baseline's and changed-cell F1 above
every baseline's).

    python experiments/heldout_table.py runs/heldout.json -o docs/results/accuracy/heldout.md \\
        --name model=bundled_v1 --name r_ft1=residual_head_ft
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from leave_one_out import table
from study import BASELINES, METRICS, stem


def collect(reports: list[Path], names: dict[str, str]) -> dict[str, dict[str, dict]]:
    """``{variant: {recording: {"model": metrics, "baselines": {name: metrics}}}}``."""
    study: dict[str, dict[str, dict]] = {}
    for report in reports:
        for recording in json.loads(report.read_text())["recordings"]:
            methods = recording["methods"]
            baselines = {b: {k: methods[b][k] for k in METRICS} for b in BASELINES}
            for key, metrics in methods.items():
                if key in BASELINES or key.startswith("copy_last_ego"):
                    continue
                variant = names.get(key, key)
                study.setdefault(variant, {})[stem(Path(recording["path"]))] = {
                    "model": {k: metrics[k] for k in METRICS},
                    "baselines": baselines,
                }
    return study


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("reports", type=Path, nargs="+", help="`lidarflow evaluate --json` files")
    parser.add_argument("-o", "--output", type=Path, required=True, help="markdown table")
    parser.add_argument(
        "--name", action="append", default=[], help="METHOD=VARIANT: rename a method (repeatable)"
    )
    args = parser.parse_args()
    names = dict(spec.partition("=")[::2] for spec in args.name)
    study = collect(args.reports, names)
    lines = table(study)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text("\n".join(lines) + "\n")
    args.output.with_suffix(".json").write_text(json.dumps(study, indent=2))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
