"""Does the online combination (:mod:`lidarflow.online`) beat every simple predictor on each
recording, one step and about one second ahead, on all cells and on movers?

Per recording: the baselines, the model (a fold's, held out, or any ``--model``) and the model
combined online with them (``NAME_combined``), scored by `lidarflow evaluate --horizon K` in
one pass (K the scans in about one second). Writes OUT/<recording>.json per recording
(resumable: kept ones are read back) and OUT/summary.json; prints per recording and method
F1, changed-cell F1 and tolerant mover F1 at k = 1 and K (the horizon tables: every k over the
same frames)::

    PYTHONPATH=src:. python -m studies.online_combination -o runs/combined \
        --fold-runs runs/movers/s0       # fold models: runs/movers/s0/<recording>/run
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from lidarflow.data.sources import load_any
from lidarflow.evaluate.combined_method import CombinedMethod
from lidarflow.evaluate.evaluation import score_one
from lidarflow.evaluate.methods import methods_and_config
from lidarflow.online.stacking import StackingConfig
from lidarflow.predict.backends import load_backend
from lidarflow.scan import GridSpec
from studies.harness import development, parse, parser, read_json, stem, write_json
from studies.movers import horizon_of

KEYS = ("f1", "changed_f1", "mover_f1_tolerant")


def score(path: Path, model: str | Path | None, config: StackingConfig) -> dict[str, Any]:
    recording = load_any(path)
    horizon = horizon_of(recording)
    methods, _ = methods_and_config([model], names=["model"])
    net, card = load_backend(model)
    methods.append(
        CombinedMethod("model_combined", net, horizon, decision=card["decision"], config=config)
    )
    start = time.perf_counter()
    scored = score_one(path.name, recording, methods, GridSpec(), 10, horizon)
    keys = scored.horizon or {}
    out: dict[str, Any] = {"horizon": horizon, "seconds": time.perf_counter() - start}
    for key in KEYS:
        table = keys.get(f"horizon_{key}", {})
        out[key] = {m: [float(v[0]), float(v[-1])] for m, v in table.items()}
    out["weights"] = methods[-1].combination.weights()
    out["chosen"] = methods[-1].combination.chosen()
    return out


def main(argv: list[str] | None = None) -> None:
    p = parser("online_combination", __doc__)
    p.add_argument("--recordings", nargs="*", type=Path, default=None)
    p.add_argument("--fold-runs", type=Path, default=None, help="FOLDER/<recording>/run models")
    p.add_argument("--model", default=None, help="one model for every recording (default bundled)")
    p.add_argument("--learning-rate", type=float, default=StackingConfig.learning_rate)
    p.add_argument("--rare-weight", type=float, default=StackingConfig.rare_weight)
    p.add_argument("--decay", type=float, default=StackingConfig.decay)
    args = parse(p, argv)
    config = StackingConfig(
        learning_rate=args.learning_rate, rare_weight=args.rare_weight, decay=args.decay
    )
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
            results[stem(path)] = write_json(target, score(path, model, config)) and read_json(
                target
            )
        show(stem(path), results[stem(path)])
    write_json(out / "summary.json", results)


def show(name: str, result: dict[str, Any]) -> None:
    print(f"\n{name} (K={result['horizon']}, {result['seconds']:.0f} s)")
    print(f"{'method':20s} " + " ".join(f"{k[:12]:>12s}@1 {k[:12]:>12s}@K" for k in KEYS))
    for method in result["f1"]:
        cells = " ".join(f"{result[k][method][0]:14.4f} {result[k][method][1]:14.4f}" for k in KEYS)
        print(f"{method:20s} {cells}")


if __name__ == "__main__":
    main()
