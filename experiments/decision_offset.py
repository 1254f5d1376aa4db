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

With --free-offsets the choice is over pairs: ``decision_offset`` for the cells occupied in the
last map (moved into the next frame by the model's flow) and ``decision_offset_free`` for the
free ones. Pairs are too many to stream each: the model is streamed once per recording (offset
0, `lidarflow evaluate`'s own loop, baselines in the same pass), and every pair is scored from
its logits at the metric's threshold. The chosen pair's model folder is then what
`lidarflow evaluate` runs on the --report recordings.

Writes OUT/offset.json (every score, the margins, the choice).
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

import numpy as np
from online_rules import collect, f1
from study import BASELINES, best_baselines, lidarflow

from lidarflow.models.presets import resolve_model


def with_offset(model: Path, offset: float, out: Path, free: float | None = None) -> Path:
    name = f"offset_{offset:g}" if free is None else f"offset_{offset:g}_free_{free:g}"
    folder = out / name
    folder.mkdir(parents=True, exist_ok=True)
    card = json.loads((model / "model.json").read_text())
    kwargs = {**card.get("model_kwargs", {}), "decision_offset": offset}
    kwargs.pop("decision_offset_free", None)
    # These offsets are scored fixed: chosen online, every copy would decide alike.
    kwargs.pop("online_decision", None)
    if free is not None:
        kwargs["decision_offset_free"] = free
    card["model_kwargs"] = kwargs
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


def pair_scores(
    model: Path, recordings: list[Path], offsets: list[float], free_offsets: list[float]
) -> dict[str, dict]:
    """``{recording: {"baselines": {...}, "occupied,free": {"f1", "changed_f1"}}}`` from one
    streaming pass per recording (``online_rules.collect``: the head's own logit, never
    re-decided online; see the module's docstring)."""
    scores = {}
    for path in recordings:
        data = collect(model, path, np.asarray(offsets), np.asarray(free_offsets))
        pairs = f1(data["pairs"].sum(axis=0))  # (A, B, [F1, changed F1])
        baselines = f1(data["baselines"].sum(axis=0))  # (3, [F1, changed F1])
        row: dict = {
            "baselines": {
                name: {"f1": float(baselines[j, 0]), "changed_f1": float(baselines[j, 1])}
                for j, name in enumerate(BASELINES)
            }
        }
        for i, a in enumerate(offsets):
            for j, b in enumerate(free_offsets):
                row[f"{a:g},{b:g}"] = {
                    "f1": float(pairs[i, j, 0]),
                    "changed_f1": float(pairs[i, j, 1]),
                }
        scores[path.name] = row
    return scores


def choose_offset_pair(
    model: Path,
    recordings: list[Path],
    offsets: list[float],
    free_offsets: list[float],
    out: Path,
) -> tuple[tuple[float, float], Path, dict, dict[str, float]]:
    """The (occupied, free) offsets with the largest summed win margin on ``recordings``, the
    model folder with them, every pair's scores and the margins."""
    cache = out / "pairs.json"
    if cache.exists():
        scores = json.loads(cache.read_text())
    else:
        scores = pair_scores(model, recordings, offsets, free_offsets)
        out.mkdir(parents=True, exist_ok=True)
        cache.write_text(json.dumps(scores, indent=1) + "\n")
    keys = [f"{a:g},{b:g}" for a in offsets for b in free_offsets]
    totals = {k: sum(margin(row[k], row["baselines"]) for row in scores.values()) for k in keys}
    best = max(totals, key=lambda k: totals[k])
    occupied, free = (float(v) for v in best.split(","))
    return (occupied, free), with_offset(model, occupied, out, free), scores, totals


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-m", "--model", type=Path, required=True)
    parser.add_argument("-o", "--output", type=Path, required=True)
    parser.add_argument("--offsets", type=float, nargs="+", default=[0.0, 0.3, 0.6, 0.9, 1.2])
    parser.add_argument("--choose", type=Path, nargs="+", required=True)
    parser.add_argument("--report", type=Path, nargs="*", default=[])
    parser.add_argument(
        "--free-offsets",
        type=float,
        nargs="*",
        default=[],
        help="choose a pair: --offsets for the cells occupied in the last map, these for the "
        "free ones",
    )
    args = parser.parse_args()
    if args.free_offsets:
        main_pairs(args)
        return
    best, models, chosen_on, totals = choose_offset(
        args.model, args.choose, args.offsets, args.output
    )
    print(
        "summed win margin on the training recordings: "
        + ", ".join(f"{o:g}: {t:+.4f}" for o, t in totals.items())
        + f" -> offset {best:g}: {models[best]} (the model with it; evaluate or predict with "
        f"-m {models[best]}, or copy its model.json's decision_offset into your run's)"
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


def main_pairs(args: argparse.Namespace) -> None:
    (occupied, free), folder, chosen_on, totals = choose_offset_pair(
        args.model, args.choose, args.offsets, args.free_offsets, args.output
    )
    print(
        f"largest summed win margin on the training recordings: {max(totals.values()):+.4f} "
        f"-> offsets {occupied:g} (occupied) / {free:g} (free): {folder}"
    )
    reported = (
        pair_scores(args.model, args.report, args.offsets, args.free_offsets) if args.report else {}
    )
    for name, row in reported.items():
        mine = row[f"{occupied:g},{free:g}"]
        print(f"{name}: {mine['f1']:.3f}/{mine['changed_f1']:.3f}")
    (args.output / "offset.json").write_text(
        json.dumps(
            {
                "model": str(args.model),
                "offsets": args.offsets,
                "free_offsets": args.free_offsets,
                "margin_on_choose": totals,
                "chosen": [occupied, free],
                "choose": chosen_on,
                "report": reported,
            },
            indent=2,
        )
        + "\n"
    )


if __name__ == "__main__":
    main()
