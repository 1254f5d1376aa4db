"""How much of `evaluate`'s verdict is noise? Each development recording scored by the default
(``lidarflow evaluate REC --horizon K``, K its scans in about one second, one thread), and each
verdict margin beside its interval over the recording's frames
(:mod:`lidarflow.evaluate.resampling`: a paired block bootstrap, 90 %).

The bundled model saw these recordings in training, so its margins are in-sample; what the
study reads is the intervals' width, which the recording, the metric and the baselines set::

    PYTHONPATH=src:. python -m studies.verdict_noise -o runs/verdict_noise

Writes OUT/<recording>.json (the evaluation; kept, so a rerun skips it) and
OUT/summary.{json,md}: per recording the margins and intervals at k = 1 and at K.

``folds DIR...`` reads instead :mod:`studies.online_combination`'s folders (one per training
seed, fold heads held out) and tables the default's margins: the model's at k = 1, the
combination's tolerant mover margin at K; writes OUT/folds.{json,md}, and where the recordings
have labelled legs or people OUT/legs.{json,md} (recall over copy-last's, precision less
copy-last's, with their intervals)::

    PYTHONPATH=src:. python -m studies.verdict_noise folds runs/oc_s0 runs/oc_s1
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from lidarflow.evaluate.resampling import MARGINS, holds
from studies.harness import (
    DEVELOPMENT,
    development,
    parse,
    parser,
    read_json,
    stem,
    write_atomic,
    write_json,
)
from studies.movers import horizon_of


def evaluate(recording: Path, out: Path) -> Path:
    """`lidarflow evaluate`'s report of ``recording`` at its K (the bundled model as the
    Predictor runs it, one thread) into OUT/<stem>.json; kept where it exists."""
    from lidarflow.data import load_any
    from lidarflow.evaluate.evaluation import evaluate_and_report
    from lidarflow.evaluate.methods import methods_and_config
    from lidarflow.evaluate.stream import WARMUP
    from lidarflow.scan import GridSpec

    path = out / f"{stem(recording)}.json"
    if path.exists():
        return path
    data = load_any(recording)
    horizon = horizon_of(data)
    methods, config = methods_and_config(
        [None], names=["bundled"], threads=1, combined_ahead=horizon
    )
    config.update({"warmup": WARMUP, "grid": GridSpec().to_dict()})
    named = [(str(recording), data)]
    write_json(
        path, evaluate_and_report(named, methods, GridSpec(), WARMUP, config, horizon=horizon)
    )
    return path


def rows(report: dict[str, Any], model: str = "bundled") -> dict[str, Any]:
    """The recording's margins and intervals of ``model``'s verdict, and the verdict."""
    entry = report["recordings"][0]
    verdict = entry["against_baselines"][model]
    out = _margins(lambda name: verdict)
    out.update(wins=verdict["wins"], horizon=len(entry["horizon_f1"]["copy_last"]))
    return out


def _margins(verdict_of: Callable[[str], dict[str, Any]]) -> dict[str, Any]:
    """``{name: {"margin", "interval"}}`` of each of :data:`MARGINS`, read from the verdict
    ``verdict_of(name)``."""
    out = {}
    for name, (key, _) in MARGINS.items():
        verdict = verdict_of(name)
        out[name] = {"margin": verdict.get(key), "interval": verdict.get("intervals", {}).get(name)}
    return out


def table(summary: dict[str, dict[str, Any]]) -> str:
    """The summary as Markdown: each margin with its interval, ``*`` where it holds 0."""
    head = (
        "| recording | K | " + " | ".join(title for _, title in MARGINS.values()) + " | verdict |"
    )
    lines = [head, "|" + "---|" * (len(MARGINS) + 3)]
    for name, row in summary.items():
        cells = []
        for key in MARGINS:
            margin, interval = row[key]["margin"], row[key]["interval"]
            if margin is None or interval is None:
                cells.append("-")
                continue
            tie = "*" if holds(interval) else ""
            cells.append(f"{margin:+.4f} ({interval[0]:+.4f}..{interval[1]:+.4f}){tie}")
        verdict = {True: "wins", False: "loses", None: "undecided"}[row["wins"]]
        lines.append(f"| {name} | {row['horizon']} | " + " | ".join(cells) + f" | {verdict} |")
    return "\n".join(lines) + "\n"


def default_rows(result: dict[str, Any]) -> dict[str, Any]:
    """The default's margins and intervals from an :mod:`studies.online_combination` result:
    the model's (it decides frame 1) at k = 1, the combination's at K."""
    model, combined = result["verdicts"]["model"], result["verdicts"]["model_combined"]
    out = _margins(lambda name: combined if name == "mover_f1_horizon" else model)
    out["horizon"] = result["horizon"]
    out["wins"] = all(
        row["margin"] is None or row["margin"] > 0 for name, row in out.items() if name in MARGINS
    )
    out["legs"] = legs_rows(result)
    return out


def legs_rows(result: dict[str, Any]) -> dict[str, Any] | None:
    """The default's labelled legs (or people) against copy-last's, from an
    :mod:`studies.online_combination` result with labels: at k = 1 the model's, at K the
    combination's recall over copy-last's and precision less copy-last's, each with its
    interval; ``None`` without labels."""
    if "legs_intervals" not in result:
        return None
    legs, spans, out = result["legs"], result["legs_intervals"], {}
    for at, method in ((0, "model"), (1, "model_combined")):
        mine, copy = legs[method], legs["copy_last"]
        recall, copy_recall = mine["recall"][at], copy["recall"][at]
        precision, copy_precision = mine["precision"][at], copy["precision"][at]
        out["k=1" if at == 0 else "K"] = {
            "recall_ratio": {
                "value": recall / copy_recall if recall is not None and copy_recall else None,
                "interval": spans[method]["recall_ratio"][at],
            },
            "precision_margin": {
                "value": None
                if None in (precision, copy_precision)
                else precision - copy_precision,
                "interval": spans[method]["precision_margin"][at],
            },
        }
    return out


def legs_table(rows: dict[str, dict[str, Any]]) -> str:
    """:func:`legs_rows` as Markdown: ``*`` where the interval holds the target's bound (a
    recall 1.5x copy-last's, a precision no lower)."""
    lines = [
        "| recording | at | recall / copy-last's | precision - copy-last's |",
        "|---|---|---|---|",
    ]
    for name, row in rows.items():
        for at, cells in row.items():
            texts = []
            for key, bound, spec in (
                ("recall_ratio", 1.5, ".2f"),
                ("precision_margin", 0.0, "+.3f"),
            ):
                value, interval = cells[key]["value"], cells[key]["interval"]
                if value is None or interval is None:
                    texts.append("-")
                    continue
                mark = "*" if holds(interval, bound) else ""
                low, high = (format(v, spec) for v in interval)
                texts.append(f"{format(value, spec)} ({low}..{high}){mark}")
            lines.append(f"| {name} | {at} | {texts[0]} | {texts[1]} |")
    return "\n".join(lines) + "\n"


def fold_table(folders: Sequence[Path]) -> dict[str, dict[str, Any]]:
    """``{"<recording> s<i>": default_rows}``, recording by recording (the development ones in
    their order, then the others), a row per seed's folder."""
    found = {p.stem for f in folders for p in f.glob("*.json") if p.name != "summary.json"}
    known = [stem(name) for name in DEVELOPMENT]
    order = sorted(found, key=lambda n: (known.index(n) if n in known else len(known), n))
    out = {}
    for name in order:
        for i, folder in enumerate(folders):
            if (folder / f"{name}.json").exists():
                out[f"{name} s{i}"] = default_rows(read_json(folder / f"{name}.json"))
    return out


def main(argv: Sequence[str] | None = None) -> None:
    p = parser("verdict_noise", __doc__)
    p.add_argument("folds", nargs="*", type=Path, help="'folds' and online_combination folders")
    args = parse(p, argv)
    out: Path = args.output
    out.mkdir(parents=True, exist_ok=True)
    if args.folds:
        if str(args.folds[0]) != "folds":
            p.error("the positional arguments are: folds DIR...")
        summary, name = fold_table(args.folds[1:]), "folds"
        legs = {n: row["legs"] for n, row in summary.items() if row.get("legs")}
        if legs:
            write_json(out / "legs.json", legs)
            write_atomic(out / "legs.md", legs_table(legs))
            print(legs_table(legs))
    else:
        summary, name = {}, "summary"
        for recording in development():
            print(f"{recording.name} ...", flush=True)
            summary[stem(recording)] = rows(read_json(evaluate(recording, out)))
    write_json(out / f"{name}.json", summary)
    write_atomic(out / f"{name}.md", table(summary))
    print(table(summary))


if __name__ == "__main__":
    main()
