"""Reproduce the paper's Table II on simulated data, with the baselines beside every row.

For each platform (static, dynamic): simulate a training and a validation set, train
LiDAR-FlowNet (paper recipe), LiDAR-FlowNet without the Gaussian filter, and DeepTracking with
the same schedule, then evaluate all of them, streaming, on the validation set next to
copy-last, temporal average and constant velocity. Every step is a `lidarflow` command (printed
before it runs), so each number can be traced and rerun by hand.

Paper scale (GPU): --train-frames 36000 --val-frames 7200 --epochs 200 --batch-size 32.
CPU scale (state it with the results): e.g. --train-frames 2000 --val-frames 400 --epochs 4.

    python experiments/reproduce_table2.py -o runs/table2 [--train-frames N] [--epochs E] ...
        [--real-train A.bag B.bag --real-eval C.bag]

With --real-train/--real-eval the three rows are also trained on real recordings and evaluated
on other ones (never on what they trained on). Writes OUT/table2.md and OUT/table2.json, and
per data set an HTML report with PR curves and
overlay GIFs (OUT/<platform>/report/index.html).
"""

from __future__ import annotations

import argparse
import json
import shlex
import subprocess
import sys
from pathlib import Path

ROWS = {
    "lidar_flownet": ["--arch", "flownet", "--recipe", "paper"],
    "lidar_flownet_no_gaussian": ["--arch", "flownet", "--recipe", "paper", "--no-gaussian"],
    "deeptracking": ["--arch", "deeptracking", "--recipe", "paper"],
}
BASELINES = ("copy_last", "temporal_average", "constant_velocity")


def lidarflow(*args: str) -> None:
    command = [sys.executable, "-m", "lidarflow.cli", *args]
    print("$ lidarflow " + shlex.join(args), flush=True)
    subprocess.run(command, check=True)


def simulated_sets(out: Path, platform: str, index: int, args: argparse.Namespace) -> None:
    for name, frames, seed in (
        ("train.npz", args.train_frames, 100 + 2 * index),
        ("val.npz", args.val_frames, 101 + 2 * index),
    ):
        if not (out / name).exists():
            lidarflow(
                "simulate", "--scenario", platform, "--frames", str(frames), "--seed", str(seed),
                "--sensor", args.sensor, "--chunk-frames", "0", "-o", str(out / name),
            )  # fmt: skip


def train_and_evaluate(
    folder: Path, train_on: list[str], evaluate_on: list[str], args: argparse.Namespace
) -> dict:
    """Train the three rows on ``train_on``, evaluate them on ``evaluate_on``; the overall row."""
    models = []
    for row, row_args in ROWS.items():
        run_dir = folder / row
        if not (run_dir / "model.safetensors").exists():
            lidarflow(
                "train", *train_on, *row_args, "-o", str(run_dir), "--epochs", str(args.epochs),
                "--batch-size", str(args.batch_size), *shlex.split(args.train_args),
            )  # fmt: skip
        models += ["--model", str(run_dir)]
    report = folder / "evaluation.json"
    if not report.exists():
        lidarflow(
            "evaluate", *evaluate_on, *models, "--json", str(report),
            "--report", str(folder / "report"),
        )  # fmt: skip
    return json.loads(report.read_text())["overall"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--output", type=Path, required=True)
    parser.add_argument("--train-frames", type=int, default=36000)
    parser.add_argument("--val-frames", type=int, default=7200)
    parser.add_argument("--epochs", type=int, default=200)
    parser.add_argument("--batch-size", type=int, default=32)
    parser.add_argument("--sensor", default="tim561")
    parser.add_argument("--platforms", nargs="*", default=["static", "dynamic"])
    parser.add_argument("--train-args", default="", help="extra arguments for every `train`")
    parser.add_argument(
        "--real-train", nargs="*", default=[], help="real recordings to train the rows on"
    )
    parser.add_argument(
        "--real-eval",
        nargs="*",
        default=[],
        help="real recordings to evaluate them on (never the training ones)",
    )
    args = parser.parse_args()
    overlap = set(map(str, args.real_train)) & set(map(str, args.real_eval))
    if overlap:
        parser.error(f"never evaluate on what the model trained on: {sorted(overlap)}")
    out: Path = args.output
    table: dict[str, dict[str, dict]] = {}
    for index, platform in enumerate(args.platforms):
        folder = out / platform
        folder.mkdir(parents=True, exist_ok=True)
        simulated_sets(folder, platform, index, args)
        table[f"sim {platform}"] = train_and_evaluate(
            folder, [str(folder / "train.npz")], [str(folder / "val.npz")], args
        )
    if args.real_train and args.real_eval:
        folder = out / "real"
        folder.mkdir(parents=True, exist_ok=True)
        table["real"] = train_and_evaluate(folder, args.real_train, args.real_eval, args)
    (out / "table2.json").write_text(json.dumps(table, indent=2))
    lines = [
        f"Table II: simulated ({args.sensor}) train {args.train_frames} / val "
        f"{args.val_frames} frames; real: train on {[Path(p).name for p in args.real_train]}, "
        f"evaluate on {[Path(p).name for p in args.real_eval]}; {args.epochs} epochs, "
        f"batch {args.batch_size} {args.train_args}",
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
    (out / "table2.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
