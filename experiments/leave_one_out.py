"""Leave-one-recording-out validation of training recipes (issue 11's ablation table).

For every variant (a name and the `lidarflow train` arguments that define it) and every
recording, train on all the *other* recordings (plus any --extra sources, e.g. simulated sets)
and evaluate, streaming, on the held-out one beside the baselines. A model "wins" on a
recording when its F1 is above the best baseline's and its changed-cell F1 above every
baseline's. Every step is a `lidarflow` command (printed before it runs); finished runs and
evaluations are reused, so an interrupted study continues where it stopped.

    python experiments/leave_one_out.py -o runs/loo \\
        --recordings ../shared/data/*.bag ../shared/data/*.bag.zip \\
        --variant "residual=--recipe residual --init runs/sim_pretrain --epochs 3" \\
        --variant "blurred=--recipe blurred --epochs 3"

Writes OUT/loo.json and OUT/loo.md (one row per variant and held-out recording).
"""

from __future__ import annotations

import argparse
import json
import shlex
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

BASELINES = ("copy_last", "temporal_average", "constant_velocity")
METRICS = ("f1", "changed_f1", "ap")


def lidarflow(*args: str) -> None:
    print("$ lidarflow " + shlex.join(args), flush=True)
    subprocess.run([sys.executable, "-m", "lidarflow.cli", *args], check=True)


def stem(path: Path) -> str:
    name = path.name
    for suffix in (".bag.zip", ".bag", ".mcap", ".npz"):
        if name.endswith(suffix):
            return name[: -len(suffix)]
    return name


def best_baselines(baselines: dict[str, dict[str, float]]) -> tuple[float, float]:
    """The best F1 and the best changed-cell F1 among the baselines (not necessarily one's)."""
    best_f1 = max(b["f1"] for b in baselines.values())
    return best_f1, max(b["changed_f1"] for b in baselines.values())


def model_and_baselines(methods: dict[str, dict]) -> dict[str, dict]:
    """``{"model": ..., "baselines": {name: ...}}`` (METRICS only) from an evaluate report's
    methods of one recording that holds one model beside the baselines."""
    (model_key,) = [k for k in methods if k not in BASELINES]
    return {
        "model": {k: methods[model_key][k] for k in METRICS},
        "baselines": {b: {k: methods[b][k] for k in METRICS} for b in BASELINES},
    }


def verdict(model: dict[str, float], baselines: dict[str, dict[str, float]]) -> str:
    best_f1, best_changed = best_baselines(baselines)
    wins_f1, wins_changed = model["f1"] > best_f1, model["changed_f1"] > best_changed
    if wins_f1 and wins_changed:
        return "wins"
    if wins_f1:
        return "F1 only"
    if wins_changed:
        return "changed only"
    return "loses"


def run_fold(
    name: str, train_args: str, recordings: list[Path], held: Path, extra: list[str], out: Path
) -> dict:
    """Train without ``held`` (unless done already), evaluate on it, return its scores."""
    folder = out / name / stem(held)
    run_dir, report = folder / "run", folder / "evaluation.json"
    if not (run_dir / "model.safetensors").exists():
        train_on = [str(r) for r in recordings if r != held] + extra
        lidarflow("train", *train_on, *shlex.split(train_args), "-o", str(run_dir))
    if not report.exists():
        lidarflow("evaluate", str(held), "--model", str(run_dir), "--json", str(report))
    return model_and_baselines(json.loads(report.read_text())["recordings"][0]["methods"])


def run_variant(
    name: str,
    train_args: str,
    recordings: list[Path],
    extra: list[str],
    out: Path,
    jobs: int = 1,
) -> dict[str, dict]:
    """All folds of one variant, ``jobs`` at a time (give each training ``--threads``)."""
    with ThreadPoolExecutor(max_workers=jobs) as pool:
        futures = {
            stem(held): pool.submit(run_fold, name, train_args, recordings, held, extra, out)
            for held in recordings
        }
        return {key: future.result() for key, future in futures.items()}


def table(study: dict[str, dict[str, dict]]) -> list[str]:
    lines = [
        "| variant | held-out recording | F1 | changed F1 | AP | best baseline F1 | "
        "best baseline changed F1 | verdict |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, per_recording in study.items():
        wins = 0
        for rec, r in per_recording.items():
            m, b = r["model"], r["baselines"]
            best_f1 = max(b, key=lambda k: b[k]["f1"])
            best_ch = max(b, key=lambda k: b[k]["changed_f1"])
            v = verdict(m, b)
            wins += v == "wins"
            lines.append(
                f"| {name} | {rec} | {m['f1']:.3f} | {m['changed_f1']:.3f} | {m['ap']:.3f} | "
                f"{b[best_f1]['f1']:.3f} ({best_f1}) | {b[best_ch]['changed_f1']:.3f} "
                f"({best_ch}) | {v} |"
            )
        lines.append(f"| {name} | **wins on {wins} of {len(per_recording)}** | | | | | | |")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--output", type=Path, required=True)
    parser.add_argument("--recordings", type=Path, nargs="+", required=True)
    parser.add_argument(
        "--variant",
        action="append",
        required=True,
        help="NAME=TRAIN_ARGS, e.g. 'residual=--recipe residual --epochs 3' (repeatable)",
    )
    parser.add_argument(
        "--extra", nargs="*", default=[], help="sources added to every training set (sim data)"
    )
    parser.add_argument(
        "--jobs",
        type=int,
        default=1,
        help="folds trained at once (default 1); on a 2-core "
        "machine use 2 with '--threads 1' in the variant's arguments",
    )
    args = parser.parse_args()
    study = {}
    for spec in args.variant:
        name, _, train_args = spec.partition("=")
        study[name] = run_variant(
            name, train_args, args.recordings, args.extra, args.output, args.jobs
        )
    args.output.mkdir(parents=True, exist_ok=True)
    (args.output / "loo.json").write_text(json.dumps(study, indent=2))
    lines = table(study)
    (args.output / "loo.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
