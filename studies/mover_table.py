"""The mover table of a leave-one-recording-out study (issue 44): per variant and held-out
recording, the model's all-cell F1 and its exact and tolerant mover F1 (inside the held-out
recording's dynamic region, :mod:`lidarflow.evaluate.movers`), beside copy-last's and the
tracker's on the same fold; then the mean of each over the folds that every variant has
finished (so that variants are compared on the same folds).

It reads what `studies.leave_one_out` left in OUT (``OUT/<variant>/<recording>/evaluation.json``)
and trains nothing:

    python -m studies.mover_table -o runs/mover_weight --variant w1 --variant w10

Writes OUT/mover_table.json and OUT/mover_table.md.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from studies.harness import (
    BASELINES,
    REFERENCES,
    parse,
    parser,
    read_json,
    split_online,
    write_summary,
)

#: the columns, in the order of the table
COLUMNS = ("f1", "mover_f1", "mover_f1_tolerant")
#: the methods beside each fold's model (copy-last; the tracker since issue 44)
BESIDE = ("copy_last", "tracker")


def fold_scores(methods: dict[str, dict]) -> dict[str, dict[str, float | None]]:
    """``{"model", "copy_last", "tracker": {column: value}}`` of one evaluation's methods
    (the model is the one method that is no baseline; ``None`` where a column is missing: the
    mover metric is undefined where nothing moved into the region)."""
    methods, _ = split_online(methods)
    models = [k for k in methods if k not in (*BASELINES, *REFERENCES)]
    if len(models) != 1:
        raise ValueError(f"expected one model among the methods, got {sorted(methods)}")
    names = {"model": models[0], **{b: b for b in BESIDE if b in methods}}
    return {label: {c: methods[name].get(c) for c in COLUMNS} for label, name in names.items()}


def mean_scores(folds: dict[str, dict[str, dict]]) -> dict[str, dict[str, float | None]]:
    """Per method and column, the mean over the folds where it is defined (``None`` if none)."""
    labels = dict.fromkeys(label for scores in folds.values() for label in scores)
    out: dict[str, dict[str, float | None]] = {}
    for label in labels:
        out[label] = {}
        for c in COLUMNS:
            values = [s[label][c] for s in folds.values() if s.get(label, {}).get(c) is not None]
            out[label][c] = sum(values) / len(values) if values else None
    return out


def _cell(value: float | None) -> str:
    return "-" if value is None else f"{value:.3f}"


def common_folds(study: dict[str, dict[str, dict]]) -> list[str]:
    """The held-out recordings that every variant of ``study`` has finished."""
    names = [set(folds) for folds in study.values()]
    return sorted(set.intersection(*names)) if names else []


def _means(study: dict[str, dict[str, dict]]) -> dict[str, dict[str, dict]]:
    shared = common_folds(study)
    return {n: mean_scores({k: f[k] for k in shared}) for n, f in study.items() if shared}


def table(study: dict[str, dict[str, dict]]) -> str:
    """Markdown: per variant one row per fold and one of the means over the common folds."""
    head = " | ".join(f"{who} {c}" for who in ("model", *BESIDE) for c in COLUMNS)
    lines = [f"| variant | held out | {head} |", "|---|---|" + "---|" * 3 * len(COLUMNS)]
    shared = common_folds(study)
    means = _means(study)
    for name, folds in study.items():
        rows = {**folds, f"**mean of {len(shared)}**": means.get(name, {})}
        for rec, scores in rows.items():
            cells = " | ".join(
                _cell(scores.get(who, {}).get(c)) for who in ("model", *BESIDE) for c in COLUMNS
            )
            lines.append(f"| {name} | {rec} | {cells} |")
    return "\n".join(lines) + "\n"


def collect(out: Path, variants: Sequence[str]) -> dict[str, dict[str, dict]]:
    """``{variant: {held-out recording: fold_scores}}`` of the finished folds in ``out``."""
    study: dict[str, dict[str, dict]] = {}
    for name in variants:
        folds = {}
        for path in sorted((out / name).glob("*/evaluation.json")):
            methods = read_json(path)["recordings"][0]["methods"]
            folds[path.parent.name] = fold_scores(methods)
        study[name] = folds
    return study


def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    p = parser("mover_table", __doc__)
    p.add_argument("--variant", action="append", required=True, help="a variant's folder name")
    args = parse(p, argv)
    study = collect(args.output, args.variant)
    if not any(study.values()):
        p.error(f"no finished fold (*/evaluation.json) under {args.output}")
    results = {"folds": study, "common_folds": common_folds(study), "means": _means(study)}
    write_summary(args, "mover_table", results, table(study))
    return results


if __name__ == "__main__":
    main()
