"""Does the online combination (:mod:`lidarflow.online`) beat every simple predictor on each
recording, one step and about one second ahead, on all cells and on movers?

Per recording: the baselines, the model (a fold's, held out, or any ``--model``) and the model
combined online with them (``NAME_combined``), scored by `lidarflow evaluate --horizon K` in
one pass (K the scans in about one second). Writes OUT/<recording>.json per recording
(resumable: kept ones are read back; ``verdicts``: evaluate's, with their margins' intervals)
and OUT/summary.json; prints per recording and method
F1, changed-cell F1 and tolerant mover F1 at k = 1 and K (the horizon tables: every k over the
same frames)::

    PYTHONPATH=src:. python -m studies.online_combination -o runs/combined \
        --fold-runs runs/movers/s0       # fold models: runs/movers/s0/<recording>/run
"""

from __future__ import annotations

import copy
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from lidarflow.data.sources import load_any
from lidarflow.evaluate.evaluation import report_of, score_one
from lidarflow.evaluate.labels import read_labels
from lidarflow.evaluate.methods import methods_and_config
from lidarflow.evaluate.model_method import ModelMethod
from lidarflow.predict.learning import LearningConfig
from lidarflow.scan import GridSpec
from studies.harness import development, parse, parser, read_json, stem, write_json
from studies.movers import horizon_of

KEYS = ("f1", "changed_f1", "mover_f1_tolerant")


class WarmUp:
    """Each method's all-cell F1 one step ahead, frame by frame (from the horizon tables'
    predictions): how many frames the combination takes to be at the best baseline."""

    def __init__(self, recording: Any) -> None:
        self.occupancy = recording.maps()[0]  # (N, H, W) bool on the default grid
        self.counts: dict[str, list[tuple[int, int, int, int]]] = {}

    def add(self, _name: str, method: str, t: int, predicted: np.ndarray) -> None:
        if t + 1 >= len(self.occupancy):
            return
        truth = self.occupancy[t + 1]
        guess = np.asarray(predicted[0]) >= 0.4
        tp = int(np.count_nonzero(guess & truth))
        fp = int(np.count_nonzero(guess)) - tp
        fn = int(np.count_nonzero(truth)) - tp
        self.counts.setdefault(method, []).append((t, tp, fp, fn))

    def frames_until(self, method: str) -> dict[str, Any]:
        """The frames from the first scored one until ``method``'s F1 over the frames so far
        is at the best baseline's and stays there (``None``: it never does), and the baseline."""

        def running(name: str) -> np.ndarray:
            c = np.cumsum(np.array(self.counts[name])[:, 1:], axis=0)
            return 2 * c[:, 0] / np.maximum(2 * c[:, 0] + c[:, 1] + c[:, 2], 1)

        present = [b for b in BASELINES if b in self.counts]
        best = np.max([running(b) for b in present], axis=0)
        below = np.flatnonzero(running(method) < best)
        until = 0 if not len(below) else int(below[-1]) + 1
        return {"frames": None if until >= len(best) else until, "scored": len(best)}


def labels_of(path: Path) -> Path | None:
    """The hand labels of a development recording: leg_tracker's labelled legs beside
    ``positive_N.bag``, the annotated people inside ``general_tracking_moving_1``."""
    extracted = path.with_name(stem(path) + "_extracted.bag")
    if extracted.exists():
        return extracted
    return path if stem(path) == "general_tracking_moving_1" else None


def learning_methods(model: ModelMethod, rates: list[float]) -> list[ModelMethod]:
    """The model again, its head learning on the stream at each Adam step size in ``rates``
    (``model_learning_RATE``), each on its own copy of the weights."""
    policy = model.engine.policy.to_record()
    out = []
    for rate in rates:
        name, backend = f"model_learning_{rate:g}", copy.deepcopy(model.backend)
        out.append(ModelMethod(name, backend, decision=policy, learning=LearningConfig(rate)))
    return out


def score(
    path: Path,
    model: str | Path | None,
    combine: bool = True,
    learn: bool = False,
    rates: list[float] | None = None,
) -> dict[str, Any]:
    recording = load_any(path)
    horizon = horizon_of(recording)
    # the model and its variants (model_combined, model_learning, ...), as evaluate makes them
    methods, _ = methods_and_config(
        [model], names=["model"], combine=horizon if combine else None, learn=learn
    )
    by_name = {m.name: m for m in methods}
    methods += learning_methods(by_name["model"], rates or [])
    labels = None
    label_file = labels_of(path)
    if label_file is not None:
        labels = read_labels(label_file, recording)
    start = time.perf_counter()
    curve = WarmUp(recording)
    scored = score_one(
        path.name, recording, methods, GridSpec(), 10, horizon, on_ahead=curve.add, labels=labels
    )
    keys = scored.horizon or {}
    out: dict[str, Any] = {"horizon": horizon, "seconds": time.perf_counter() - start}
    # evaluate's verdicts, with their margins' intervals over the frames (studies.verdict_noise)
    out["verdicts"] = report_of([(path.name, scored)], {})["recordings"][0]["against_baselines"]
    ours = [m for m in methods if m.name.startswith("model")]
    out["warm_up"] = {m.name: curve.frames_until(m.name) for m in ours}
    for key in KEYS:
        table = keys.get(f"horizon_{key}", {})
        out[key] = {m: [float(v[0]), float(v[-1])] for m, v in table.items()}
    if "legs" in scored.notes:
        legs = scored.notes["legs"]
        out["legs"] = {m: {k: [v[0], v[-1]] for k, v in legs[m].items()} for m in legs}
        spans = scored.notes["legs_intervals"]  # over copy-last's, k = 1 and K
        out["legs_intervals"] = {m: {k: [v[0], v[-1]] for k, v in spans[m].items()} for m in spans}
    if "model_combined" in by_name:
        out["weights"] = by_name["model_combined"].combination.weights()
        out["chosen"] = by_name["model_combined"].combination.chosen()
    out["learning"] = {m.name: _learnt(m) for m in ours if _learnt(m)}
    return out


def _learnt(method: Any) -> dict[str, Any] | None:
    """What a method's head learnt on the recording (``None``: it does not learn)."""
    engine = getattr(method, "model", method).engine  # a CombinedMethod wraps its model
    learning = engine.learning
    if learning is None:
        return None
    return {"frames": learning.frames, "fallbacks": learning.fallbacks,
            "loss": learning.loss, "shipped_loss": learning.shipped_loss}  # fmt: skip


def main(argv: list[str] | None = None) -> None:
    p = parser("online_combination", __doc__)
    p.add_argument("--recordings", nargs="*", type=Path, default=None)
    p.add_argument("--fold-runs", type=Path, default=None, help="FOLDER/<recording>/run models")
    p.add_argument("--model", default=None, help="one model for every recording (default bundled)")
    p.add_argument("--no-combine", action="store_true", help="leave the combination out")
    p.add_argument("--learn", action="store_true", help="also the model learning on the stream")
    p.add_argument("--learn-rates", nargs="*", type=float, default=[],
                   help="also the model learning at these step sizes")  # fmt: skip
    args = parse(p, argv)
    out: Path = args.output
    results = {}
    for path in args.recordings or development():
        target = out / f"{stem(path)}.json"
        if target.exists():
            results[stem(path)] = read_json(target)
        else:
            model = args.model
            if args.fold_runs is not None:
                model = args.fold_runs / stem(path) / "run"
            result = score(path, model, not args.no_combine, args.learn, args.learn_rates)
            results[stem(path)] = write_json(target, result) and read_json(target)
        show(stem(path), results[stem(path)])
    write_json(out / "summary.json", results)


def show(name: str, result: dict[str, Any]) -> None:
    print(f"\n{name} (K={result['horizon']}, {result['seconds']:.0f} s)")
    print(f"{'method':20s} " + " ".join(f"{k[:12]:>12s}@1 {k[:12]:>12s}@K" for k in KEYS))
    for method in result["f1"]:
        cells = " ".join(f"{result[k][method][0]:14.4f} {result[k][method][1]:14.4f}" for k in KEYS)
        print(f"{method:20s} {cells}")


BASELINES = ("copy_last", "temporal_average", "constant_velocity", "tracker", "copy_last_ego")
KEYS_SHOWN = {"f1": "F1", "changed_f1": "changed F1", "mover_f1_tolerant": "tolerant mover F1"}


def margins(result: dict[str, Any], method: str, at: int) -> dict[str, float]:
    """``method``'s margins at step index ``at`` (0: k = 1, 1: K), as `evaluate` judges: F1
    and changed-cell F1 over the best baseline, tolerant mover F1 over copy-last."""
    present = [b for b in BASELINES if b in result["f1"]]
    out = {}
    for key in KEYS:
        if key == "mover_f1_tolerant":
            best = result[key]["copy_last"][at]
        else:
            best = max(result[key][b][at] for b in present)
        out[key] = result[key][method][at] - best
    return out


def table(folders: list[Path], methods: tuple[str, ...] = ("model", "model_combined")) -> str:
    """Markdown: per recording and method, the mean over ``folders`` (one per training seed)
    of each metric at k = 1 and K, its margin as `evaluate` judges, and the verdict."""
    runs = [read_json(folder / "summary.json") for folder in folders]
    lines = [
        "| recording (K) | method | at | F1 | changed F1 | tolerant mover F1 | margins "
        "(F1 / changed / mover) | wins |",
        "|---|---|---|---|---|---|---|---|",
    ]
    totals: dict[tuple[str, int], list[dict[str, float]]] = {}
    for name in runs[0]:
        per_seed = [run[name] for run in runs if name in run]
        for method in (*methods, "copy_last", "temporal_average", "tracker"):
            for at, label in ((0, "k=1"), (1, "~1 s")):
                values = [np.mean([r[k][method][at] for r in per_seed]) for k in KEYS]
                row = f"| {name} ({per_seed[0]['horizon']}) | {method} | {label} | "
                row += " | ".join(f"{v:.4f}" for v in values)
                if method in methods:
                    m = [margins(r, method, at) for r in per_seed]
                    mean = {k: float(np.mean([x[k] for x in m])) for k in KEYS}
                    totals.setdefault((method, at), []).append(mean)
                    wins = sum(all(x[k] > 0 for k in KEYS) for x in m)
                    row += " | " + " / ".join(f"{mean[k]:+.4f}" for k in KEYS)
                    row += f" | {wins}/{len(m)} |"
                else:
                    row += " | | |"
                lines.append(row)
    lines += [
        "",
        "| method | at | mean margins (F1 / changed / mover) | worst fold | folds won |",
        "|---|---|---|---|---|",
    ]
    for (method, at), folds in totals.items():
        mean = " / ".join(f"{np.mean([f[k] for f in folds]):+.4f}" for k in KEYS)
        worst = " / ".join(f"{min(f[k] for f in folds):+.4f}" for k in KEYS)
        won = sum(all(f[k] > 0 for k in KEYS) for f in folds)
        lines.append(
            f"| {method} | {('k=1', '~1 s')[at]} | {mean} | {worst} | {won}/{len(folds)} |"
        )
    return "\n".join(lines)


def legs_table(folders: list[Path], methods: tuple[str, ...]) -> str:
    """Markdown: per labelled recording and method, the labelled legs (or people) found within
    0.3 m (recall) and the predicted dynamic cells near one (precision), at k = 1 and K, the
    mean over ``folders`` (one per training seed)."""
    runs = [read_json(folder / "summary.json") for folder in folders]
    lines = ["| recording | method | recall k=1 | recall ~1 s | precision k=1 | precision ~1 s |",
             "|---|---|---|---|---|---|"]  # fmt: skip
    for name in runs[0]:
        legs = [run[name]["legs"] for run in runs if "legs" in run.get(name, {})]
        if not legs:
            continue
        for method in ("copy_last", "tracker", *methods):
            cells = [np.mean([leg[method][key][at] for leg in legs])
                     for key in ("recall", "precision") for at in (0, 1)]  # fmt: skip
            lines.append(f"| {name} | {method} | " + " | ".join(f"{c:.3f}" for c in cells) + " |")
    return "\n".join(lines)


if __name__ == "__main__":
    if sys.argv[1:2] == ["table"]:  # table FOLDER... [--methods NAME...]
        args = sys.argv[2:]
        shown = args[args.index("--methods") + 1 :] if "--methods" in args else []
        folders = args[: args.index("--methods")] if shown else args
        print(table([Path(f) for f in folders], *([tuple(shown)] if shown else [])))
        if shown:
            print()
            print(legs_table([Path(f) for f in folders], tuple(shown)))
    else:
        main()
