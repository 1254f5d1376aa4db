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

With --online-decision every fold's model is evaluated with its decision offsets chosen on
the held-out recording as it streams (`lidarflow evaluate --online-decision`; past frames
only); the table scores that, and each fold's JSON keeps the fixed offsets' scores beside it.

Writes OUT/loo.json and OUT/loo.md (one row per variant and held-out recording).
"""

from __future__ import annotations

import argparse
import json
import shlex
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from decision_offset import choose_offset, choose_offset_pair
from study import METRICS, lidarflow, model_and_baselines, split_online, stem, verdict


def run_fold(
    name: str,
    train_args: str,
    recordings: list[Path],
    held: Path,
    extra: list[str],
    out: Path,
    offsets: list[float] | None = None,
    free_offsets: list[float] | None = None,
    online: bool = False,
) -> dict:
    """Train without ``held`` (unless done already), with ``offsets`` choose the decision
    offset on the fold's own (real) training recordings (with ``free_offsets`` too, a pair:
    occupied cells', free cells'), evaluate on ``held`` (``online``: also with the offsets
    chosen as it streams, which is then the model scored), return its scores (and the offset
    chosen)."""
    folder = out / name / stem(held)
    run_dir, report = folder / "run", folder / "evaluation.json"
    train_on = [r for r in recordings if r != held]
    if not (run_dir / "model.safetensors").exists():
        lidarflow(
            "train", *map(str, train_on), *extra, *shlex.split(train_args), "-o", str(run_dir)
        )
    model, chosen, margins, free = run_dir, None, {}, None
    if offsets and free_offsets:
        (chosen, free), model, _, margins = choose_offset_pair(
            run_dir, train_on, offsets, free_offsets, folder / "offset_pairs"
        )
        report = folder / "evaluation_pair.json"
    elif offsets:
        chosen, models, _, margins = choose_offset(run_dir, train_on, offsets, folder / "offset")
        model = models[chosen]
    if online:
        report = report.with_name(report.stem + "_online.json")
    if not report.exists():
        flags = ["--online-decision"] if online else []
        lidarflow("evaluate", str(held), "--model", str(model), *flags, "--json", str(report))
    methods = json.loads(report.read_text())["recordings"][0]["methods"]
    fixed = None
    if online:
        methods, fixed = split_online(methods)
    scores = model_and_baselines(methods)
    if fixed is not None:
        scores = {
            **scores,
            "online_decision": True,
            "fixed_offsets": {k: fixed[k] for k in METRICS},
        }
    if chosen is None:
        return scores
    # The summed win margin of every offset on the fold's training recordings: why this one.
    chosen_offsets = {"decision_offset": chosen}
    if free is not None:
        chosen_offsets["decision_offset_free"] = free
    return {
        **scores,
        **chosen_offsets,
        "offset_margins": {str(o): m for o, m in margins.items()},
    }


def run_variant(
    name: str,
    train_args: str,
    recordings: list[Path],
    extra: list[str],
    out: Path,
    jobs: int = 1,
    offsets: list[float] | None = None,
    held_out: list[Path] | None = None,
    free_offsets: list[float] | None = None,
    online: bool = False,
) -> dict[str, dict]:
    """The folds of one variant (every recording held out in turn, or those of ``held_out``),
    ``jobs`` at a time (give each training ``--threads``)."""
    with ThreadPoolExecutor(max_workers=jobs) as pool:
        futures = {
            stem(held): pool.submit(
                run_fold,
                name,
                train_args,
                recordings,
                held,
                extra,
                out,
                offsets,
                free_offsets,
                online,
            )
            for held in (held_out or recordings)
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
            if r.get("online_decision"):
                rec = f"{rec} (offsets online)"
            elif "decision_offset_free" in r:
                rec = f"{rec} (offsets {r['decision_offset']:g} / {r['decision_offset_free']:g})"
            elif "decision_offset" in r:
                rec = f"{rec} (offset {r['decision_offset']:g})"
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
    parser.add_argument(
        "--offsets",
        type=float,
        nargs="*",
        default=[],
        help="decision offsets to choose from per fold, on that fold's training recordings "
        "(occupancy-head models; experiments/decision_offset.py); none: no offset",
    )
    parser.add_argument(
        "--free-offsets",
        type=float,
        nargs="*",
        default=[],
        help="with --offsets: choose a pair per fold, --offsets for the cells occupied in the "
        "last map and these for the free ones (model.kwargs.decision_offset_free)",
    )
    parser.add_argument(
        "--held-out",
        type=Path,
        nargs="*",
        default=[],
        help="run only the folds holding out these (some of --recordings; default: every one)",
    )
    parser.add_argument(
        "--online-decision",
        action="store_true",
        help="score each fold's model with its decision offsets chosen online on the held-out "
        "recording (lidarflow evaluate --online-decision); the fixed offsets' scores are kept "
        "in loo.json",
    )
    args = parser.parse_args()
    if args.free_offsets and not args.offsets:
        parser.error("--free-offsets needs --offsets (the occupied cells' offsets of each pair)")
    if unknown := [str(p) for p in args.held_out if p not in args.recordings]:
        parser.error(f"--held-out must be among --recordings: {', '.join(unknown)}")
    study = {}
    for spec in args.variant:
        name, _, train_args = spec.partition("=")
        study[name] = run_variant(
            name,
            train_args,
            args.recordings,
            args.extra,
            args.output,
            args.jobs,
            args.offsets,
            args.held_out,
            args.free_offsets,
            args.online_decision,
        )
    args.output.mkdir(parents=True, exist_ok=True)
    (args.output / "loo.json").write_text(json.dumps(study, indent=2))
    lines = table(study)
    (args.output / "loo.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
