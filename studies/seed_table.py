"""Leave-one-out verdicts over several training seeds of one recipe (issue 11).

A fold's verdict on a static recording turns on margins of a thousandth, which is about what
a training seed moves. So one seed's "wins on 7 of 7" says little on its own: this script lays
the same recipe's folds, trained with several seeds, side by side, per held-out recording.

Each run is a folder of ``lidarflow evaluate --online-decision`` reports, one per held-out
recording, named ``eval_REC.json``, or a path with ``{}`` where the recording's name goes
(``other_sensors/eval/{}__recorded.json``):

    python -m studies.seed_table -o runs/studies/seeds \\
        --run s0=runs/loo_s0 --run s1=runs/loo_s1 --run s2=runs/loo_s2 \\
        --run s0_again=runs/studies/other_sensors/{}__recorded.json

(reports of `lidarflow evaluate --online-decision --json`; the folds of
``studies.leave_one_out --online-decision`` are
``--run s0=runs/studies/leave_one_out/head/{}/evaluation_online.json``.)

Writes OUT/seeds.json (per recording and run: the model's and the baselines' scores, the
margins over the best baselines, the verdict) and OUT/seeds.md (the table, and per recording
the runs won, the mean and the smallest margin).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from studies.harness import DEVELOPMENT, judged, parse, parser, read_json, stem, write_summary


def scores_of(report: Path) -> dict[str, Any]:
    """The online-decided model's scores, the baselines', the margins and the verdict."""
    methods = read_json(report)["recordings"][0]["methods"]
    return {**judged(methods), "report": str(report)}


def collect(runs: dict[str, str], recordings: list[str]) -> dict[str, dict[str, dict]]:
    """``{recording: {run: scores}}`` for every report found (a run may lack a recording);
    ``runs`` maps a run's name to its reports' path with ``{}`` for the recording."""
    table: dict[str, dict[str, dict]] = {}
    for name in recordings:
        for run, template in runs.items():
            report = Path(template.format(name))
            if report.exists():
                table.setdefault(name, {})[run] = scores_of(report)
    return table


def markdown(table: dict[str, dict[str, dict]], runs: list[str]) -> str:
    """Per recording: each run's F1 / changed-cell F1 margins (bold unless a win), the runs
    won, the mean and the smallest of the two margins' smaller one."""
    lines = [
        "| held-out recording | "
        + " | ".join(runs)
        + " | runs won | mean margin | smallest margin |",
        "|---" * (len(runs) + 4) + "|",
    ]
    won_by_run = dict.fromkeys(runs, 0)
    for name, by_run in table.items():
        cells, smaller, won = [], [], 0
        for run in runs:
            if run not in by_run:
                cells.append("")
                continue
            s = by_run[run]
            cell = f"{s['margins']['f1']:+.4f} / {s['margins']['changed_f1']:+.4f}"
            if s["verdict"] == "wins":
                won_by_run[run] += 1
                won += 1
            else:
                cell = f"**{cell}** ({s['verdict']})"
            cells.append(cell)
            smaller.append(min(s["margins"].values()))
        mean = sum(smaller) / len(smaller)
        lines.append(
            f"| {name} | " + " | ".join(cells) + f" | {won} of {len(smaller)} | "
            f"{mean:+.4f} | {min(smaller):+.4f} |"
        )
    scored = {r: sum(r in by_run for by_run in table.values()) for r in runs}
    lines.append(
        "| **recordings won** | "
        + " | ".join(f"**{won_by_run[r]} of {scored[r]}**" for r in runs)
        + " | | | |"
    )
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> dict[str, dict[str, dict]]:
    p = parser("seed_table", __doc__)
    p.add_argument(
        "--run",
        action="append",
        required=True,
        metavar="NAME=PATH",
        help="a run's name and its folder of eval_REC.json reports, or their path with {} for "
        "the recording's name (repeatable, in table order)",
    )
    p.add_argument(
        "--recordings", nargs="+", default=[stem(name) for name in DEVELOPMENT],
        help="the held-out recordings' names, as in eval_NAME.json (default: the seven)",
    )  # fmt: skip
    args = parse(p, argv)
    runs: dict[str, str] = {}
    for spec in args.run:
        name, sep, path = spec.partition("=")
        if "{}" not in path and Path(path).is_dir():
            path = str(Path(path) / "eval_{}.json")
        if not sep or not name or "{}" not in path or not Path(path.format("")).parent.is_dir():
            p.error(f"--run wants NAME=FOLDER or NAME=PATH with {{}}, got {spec!r}")
        runs[name] = path
    table = collect(runs, args.recordings)
    if not table:
        p.error("no report found for any recording in any run")
    write_summary(args, "seeds", table, markdown(table, list(runs)))
    return table


if __name__ == "__main__":
    main()
