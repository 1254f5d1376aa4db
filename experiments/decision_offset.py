"""Choose an occupancy-head model's decision offset on its training recordings (issue 11).

The head is trained by cross-entropy, so its probabilities are calibrated and it predicts a
cell that changes only when the change is likelier than the 0.4 threshold. Adding an offset to
its logit when predicting (`model.kwargs.decision_offset`) trades calibration for cells that
change. For each offset this script writes a copy of the model folder with that offset, runs
`lidarflow evaluate` (all offsets in one streaming pass) on the --choose recordings, and picks
the offset with the largest summed *win margin*, ``min(F1 - best baseline F1, changed F1 - best
baseline changed F1)`` per recording (positive exactly when the model wins there). The
--report recordings (ones the model never saw) are then evaluated for every offset too, to
report, not to choose.

    python experiments/decision_offset.py -m src/lidarflow/assets/model -o runs/offset \\
        --offsets 0 0.3 0.6 0.9 1.2 --choose ../shared/data/positive_{1,3,4}.bag \\
        --report ../shared/data/positive_2.bag

Writes OUT/offset.json (every score, the margins, the choice).
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

from study import BASELINES, best_baselines, lidarflow

from lidarflow.models.presets import resolve_model


def with_offset(model: Path, offset: float, out: Path) -> Path:
    folder = out / f"offset_{offset:g}"
    folder.mkdir(parents=True, exist_ok=True)
    card = json.loads((model / "model.json").read_text())
    card["model_kwargs"] = {**card.get("model_kwargs", {}), "decision_offset": offset}
    (folder / "model.json").write_text(json.dumps(card, indent=2))
    shutil.copy(model / card.get("weights", "model.safetensors"), folder / "model.safetensors")
    resolve_model(folder)  # fails here, in one place, if the model has no occupancy head
    return folder


def evaluate(recordings: list[Path], models: dict[float, Path], report: Path) -> dict:
    """``{recording: {offset: {"f1", "changed_f1"}, "baselines": {...}}}``."""
    if not report.exists():
        model_args = [a for folder in models.values() for a in ("-m", str(folder))]
        lidarflow("evaluate", *map(str, recordings), *model_args, "--json", str(report))
    scores: dict[str, dict] = {}
    for entry in json.loads(report.read_text())["recordings"]:
        methods = entry["methods"]
        name = Path(entry["path"]).name
        row: dict = {"baselines": {b: methods[b] for b in BASELINES}}
        for offset, folder in models.items():
            row[str(offset)] = methods[folder.name]
        scores[name] = row
    return scores


def margin(result: dict, baselines: dict) -> float:
    best_f1, best_changed = best_baselines(baselines)
    return min(result["f1"] - best_f1, result["changed_f1"] - best_changed)


def choose_offset(
    model: Path, recordings: list[Path], offsets: list[float], out: Path
) -> tuple[float, dict[float, Path], dict, dict[float, float]]:
    """The offset with the largest summed win margin on ``recordings``; also every offset's
    model folder, the scores and the margins."""
    models = {o: with_offset(model, o, out) for o in offsets}
    scores = evaluate(recordings, models, out / "choose.json")
    totals = {
        o: sum(margin(row[str(o)], row["baselines"]) for row in scores.values()) for o in offsets
    }
    return max(totals, key=lambda o: totals[o]), models, scores, totals


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-m", "--model", type=Path, required=True)
    parser.add_argument("-o", "--output", type=Path, required=True)
    parser.add_argument("--offsets", type=float, nargs="+", default=[0.0, 0.3, 0.6, 0.9, 1.2])
    parser.add_argument("--choose", type=Path, nargs="+", required=True)
    parser.add_argument("--report", type=Path, nargs="*", default=[])
    args = parser.parse_args()
    best, models, chosen_on, totals = choose_offset(
        args.model, args.choose, args.offsets, args.output
    )
    print(
        "summed win margin on the training recordings: "
        + ", ".join(f"{o:g}: {t:+.4f}" for o, t in totals.items())
        + f" -> offset {best:g}"
    )
    reported = evaluate(args.report, models, args.output / "report.json") if args.report else {}
    for name, row in reported.items():
        print(
            name
            + ": "
            + ", ".join(
                f"{o:g}: {row[str(o)]['f1']:.3f}/{row[str(o)]['changed_f1']:.3f}"
                for o in args.offsets
            )
        )
    (args.output / "offset.json").write_text(
        json.dumps(
            {
                "model": str(args.model),
                "offsets": args.offsets,
                "margin_on_choose": {str(o): t for o, t in totals.items()},
                "chosen": best,
                "choose": chosen_on,
                "report": reported,
            },
            indent=2,
        )
        + "\n"
    )


if __name__ == "__main__":
    main()
