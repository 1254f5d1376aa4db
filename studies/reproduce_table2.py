"""Reproduce the paper's Table II on simulated data, with the baselines beside every row.

For each platform (static, dynamic): simulate a training and a validation set, train
LiDAR-FlowNet (paper recipe), LiDAR-FlowNet without the Gaussian filter, and DeepTracking with
the same schedule, then evaluate all of them, streaming, on the validation set next to
copy-last, temporal average and constant velocity. Finished sets and runs are reused.

Paper scale (GPU): --train-frames 36000 --val-frames 7200 --epochs 200 --batch-size 32.
CPU scale (state it with the results): e.g. --train-frames 2000 --val-frames 400 --epochs 4.

    python -m studies.reproduce_table2 -o runs/studies/table2 [--train-frames N] [--epochs E]
        [--set KEY=VALUE ...] [--real-train A.bag B.bag --real-eval C.bag]

With --real-train/--real-eval the three rows are also trained on real recordings and evaluated
on other ones (never on what they trained on). Writes OUT/table2.md and OUT/table2.json, and
per data set the evaluation and an HTML report with PR curves and overlay GIFs
(OUT/<platform>/report/index.html; not with --no-report).
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from lidarflow.data import load_any
from lidarflow.sim import SimConfig, lidar_preset, write_simulation
from studies.folds import train_model
from studies.harness import BASELINES, parse, parser, write_json, write_summary
from studies.scoring import evaluate

# row -> the `lidarflow train` settings that define it (the paper's recipe for all three)
ROWS: dict[str, dict[str, Any]] = {
    "lidar_flownet": {"model.name": "flownet"},
    "lidar_flownet_no_gaussian": {"model.name": "flownet", "schedule.gaussian": False},
    "deeptracking": {"model.name": "deeptracking"},
}


def simulated_sets(out: Path, platform: str, index: int, args: argparse.Namespace) -> None:
    """``train.npz`` and ``val.npz`` of ``platform`` in ``out`` (seeds apart per platform)."""
    config = SimConfig(scenario=platform, sensor=lidar_preset(args.sensor))
    for name, frames, seed in (
        ("train.npz", args.train_frames, 100 + 2 * index),
        ("val.npz", args.val_frames, 101 + 2 * index),
    ):
        if not (out / name).exists():
            write_simulation(out / name, frames, seed, config)


def train_and_evaluate(
    folder: Path, train_on: list[Path], evaluate_on: list[Path], args: argparse.Namespace
) -> dict[str, Any]:
    """Train the three rows on ``train_on``, evaluate them on ``evaluate_on``; the overall row."""
    schedule = {"optim.epochs": args.epochs, "optim.batch_size": args.batch_size}
    models = {
        row: train_model(train_on, folder / row, "paper", args.set, {**flags, **schedule})
        for row, flags in ROWS.items()
    }
    recordings = [(str(path), load_any(path)) for path in evaluate_on]
    report_dir = None if args.no_report else folder / "report"
    report = evaluate(recordings, models, report_dir=report_dir)
    write_json(folder / "evaluation.json", report)
    return report["overall"]


def markdown(table: dict[str, dict[str, Any]], args: argparse.Namespace) -> str:
    lines = [
        f"Table II: simulated ({args.sensor}) train {args.train_frames} / val "
        f"{args.val_frames} frames; real: train on {[Path(p).name for p in args.real_train]}, "
        f"evaluate on {[Path(p).name for p in args.real_eval]}; {args.epochs} epochs, "
        f"batch {args.batch_size} {' '.join(args.set)}",
        "",
        "| data | method | F1 | precision | recall | AP | changed-cell F1 | EPE |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for data, methods in table.items():
        for name in (*ROWS, *BASELINES):
            m = methods.get(name)
            if m is None:
                continue
            epe = f"{m['epe']:.3f}" if m.get("epe") is not None else "-"
            lines.append(
                f"| {data} | {name} | {m['f1']:.3f} | {m['precision']:.3f} | "
                f"{m['recall']:.3f} | {m['ap']:.3f} | {m['changed_f1']:.3f} | {epe} |"
            )
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> dict[str, dict[str, Any]]:
    p = parser("reproduce_table2", __doc__)
    p.add_argument("--train-frames", type=int, default=36000)
    p.add_argument("--val-frames", type=int, default=7200)
    p.add_argument("--epochs", type=int, default=200)
    p.add_argument("--batch-size", type=int, default=32)
    p.add_argument("--sensor", default="tim561")
    p.add_argument("--platforms", nargs="*", default=["static", "dynamic"])
    p.add_argument(
        "--set",
        nargs="*",
        default=[],
        metavar="KEY=VALUE",
        help="config keys for every training (as `lidarflow train --set`)",
    )
    p.add_argument(
        "--real-train",
        type=Path,
        nargs="*",
        default=[],
        help="real recordings to train the rows on",
    )
    p.add_argument(
        "--real-eval",
        type=Path,
        nargs="*",
        default=[],
        help="real recordings to evaluate them on (never the training ones)",
    )
    p.add_argument("--no-report", action="store_true", help="no HTML report (figures, GIFs)")
    args = parse(p, argv)  # fmt: skip
    if overlap := set(args.real_train) & set(args.real_eval):
        p.error(f"never evaluate on what the model trained on: {sorted(map(str, overlap))}")
    table: dict[str, dict[str, Any]] = {}
    for index, platform in enumerate(args.platforms):
        folder = args.output / platform
        folder.mkdir(parents=True, exist_ok=True)
        simulated_sets(folder, platform, index, args)
        table[f"sim {platform}"] = train_and_evaluate(
            folder, [folder / "train.npz"], [folder / "val.npz"], args
        )
    if args.real_train and args.real_eval:
        table["real"] = train_and_evaluate(
            args.output / "real", args.real_train, args.real_eval, args
        )
    write_summary(args, "table2", table, markdown(table, args))
    return table


if __name__ == "__main__":
    main()
