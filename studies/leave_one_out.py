"""Leave-one-recording-out validation of training recipes (the fold table).

For every variant (a name, a `lidarflow train` recipe and the config keys it sets) and every
recording, train on all the *other* recordings (plus any --extra sources, e.g. simulated sets)
and evaluate, streaming, on the held-out one beside the baselines. A model "wins" on a
recording when its F1 is above the best baseline's and its changed-cell F1 above every
baseline's. Finished runs are reused, so an interrupted study continues where it stopped.

    python -m studies.leave_one_out -o runs/studies/leave_one_out \\
        --recordings ../shared/data/*.bag ../shared/data/*.bag.zip \\
        --variant "head=head optim.epochs=3" --variant "blurred=blurred optim.epochs=3"

With --online-decision every fold's model is also scored with the other decision rule (offsets
chosen online on the held-out recording as it streams, or fixed); the table scores the model's
own rule and the JSON keeps the other's scores beside it.

Writes OUT/leave_one_out.json and OUT/leave_one_out.md (one row per variant and recording);
each fold's run and evaluation in OUT/<variant>/<recording>/.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from studies.folds import Variant, train_variant
from studies.harness import (
    METRICS,
    development,
    model_and_baselines,
    parse,
    parser,
    read_json,
    split_online,
    stem,
    verdict,
    write_json,
    write_summary,
)


def run_fold(
    variant: Variant,
    recordings: list[Path],
    held: Path,
    extra: list[Path],
    out: Path,
    online: bool = False,
) -> dict[str, Any]:
    """Train without ``held`` (unless done already), evaluate on ``held``; its scores."""
    from lidarflow.data import load_any
    from studies.scoring import evaluate

    folder = out / variant.name / stem(held)
    train_on = [r for r in recordings if r != held] + extra
    run_dir = train_variant(variant, train_on, folder / "run")
    report_path = folder / ("evaluation_online.json" if online else "evaluation.json")
    if not report_path.exists():
        report = evaluate([(str(held), load_any(held))], {"model": run_dir}, online)
        write_json(report_path, report)
    methods, other = split_online(read_json(report_path)["recordings"][0]["methods"])
    scores: dict[str, Any] = model_and_baselines(methods)
    if other is not None:
        scores["other_rule"] = {k: other[k] for k in METRICS}
    return scores


def table(study: dict[str, dict[str, dict]]) -> str:
    """Markdown: one row per variant and held-out recording, and the wins per variant."""
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
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> dict[str, dict[str, dict]]:
    p = parser("leave_one_out", __doc__)
    p.add_argument(
        "--recordings",
        type=Path,
        nargs="+",
        default=development(),
        help="the recordings held out in turn (default: the development ones)",
    )
    p.add_argument(
        "--variant",
        type=Variant.parse,
        action="append",
        required=True,
        help="NAME=RECIPE [KEY=VALUE ...], e.g. 'head=head optim.epochs=3'",
    )
    p.add_argument(
        "--extra",
        type=Path,
        nargs="*",
        default=[],
        help="sources added to every training set (simulated data)",
    )
    p.add_argument(
        "--held-out",
        type=Path,
        nargs="*",
        default=[],
        help="run only the folds holding out these (some of --recordings)",
    )
    p.add_argument(
        "--online-decision",
        action="store_true",
        help="also score each fold's model with the other decision rule",
    )
    args = parse(p, argv)  # fmt: skip
    if unknown := [str(r) for r in args.held_out if r not in args.recordings]:
        p.error(f"--held-out must be among --recordings: {', '.join(unknown)}")
    if len(args.recordings) < 2:
        p.error("leave-one-out needs two recordings at least")
    study = {
        variant.name: {
            stem(held): run_fold(
                variant, args.recordings, held, args.extra, args.output, args.online_decision
            )
            for held in (args.held_out or args.recordings)
        }
        for variant in args.variant
    }
    write_summary(args, "leave_one_out", study, table(study))
    return study


if __name__ == "__main__":
    main()
