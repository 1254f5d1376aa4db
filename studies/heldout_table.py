"""The held-out table of models already trained, from evaluation reports.

Where the models were trained elsewhere (the same training recordings, different recipes), this
turns their evaluations on recordings none of them trained on into the table that
``studies.leave_one_out`` writes: one row per model and recording, F1 / changed-cell F1 / AP
beside the best baselines, and the verdict ("wins" = F1 above the best baseline's and
changed-cell F1 above every baseline's).

    python -m studies.heldout_table runs/heldout.json -o runs/studies/heldout \\
        --name model=bundled_v1 --name r_ft1=residual_head_ft

Writes OUT/heldout.json and OUT/heldout.md.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from studies.harness import BASELINES, METRICS, parse, parser, read_json, stem, write_summary
from studies.leave_one_out import table


def collect(reports: list[Path], names: dict[str, str]) -> dict[str, dict[str, dict]]:
    """``{variant: {recording: {"model": metrics, "baselines": {name: metrics}}}}``."""
    study: dict[str, dict[str, dict]] = {}
    for report in reports:
        for recording in read_json(report)["recordings"]:
            methods = recording["methods"]
            baselines = {b: {k: methods[b][k] for k in METRICS} for b in BASELINES if b in methods}
            for key, metrics in methods.items():
                if key in BASELINES or key.startswith("copy_last_ego"):
                    continue
                variant = names.get(key, key)
                study.setdefault(variant, {})[stem(recording["path"])] = {
                    "model": {k: metrics[k] for k in METRICS},
                    "baselines": baselines,
                }
    return study


def main(argv: Sequence[str] | None = None) -> dict[str, dict[str, dict]]:
    p = parser("heldout_table", __doc__)
    p.add_argument("reports", type=Path, nargs="+", help="`lidarflow evaluate` reports (JSON)")
    p.add_argument(
        "--name", action="append", default=[], help="METHOD=VARIANT: rename a method (repeatable)"
    )
    args = parse(p, argv)
    names = dict(spec.partition("=")[::2] for spec in args.name)
    study = collect(args.reports, names)
    write_summary(args, "heldout", study, table(study))
    return study


if __name__ == "__main__":
    main()
