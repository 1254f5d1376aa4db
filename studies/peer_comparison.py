"""Issue 38's comparison: LiDAR-FlowNet (the bundled recipe, fold-clean), SOGMP and DeepTracking,
each trained leave-one-recording-out on the development recordings and scored on the held-out
one beside the baselines, one step and about one second ahead, in both conventions (F1 and
changed-cell F1; the peers' WMSE and SSIM).

Three steps, each a subcommand, so that training can go where the compute is (a GPU, or
several processes) and the scoring and the table follow::

    python -m studies.peer_comparison train -o OUT --model sogmp --jobs 2 \\
        --recordings R1.npz R2.npz ... --set runtime.amp=auto runtime.max_minutes=1.3
    python -m studies.peer_comparison evaluate -o OUT --recordings R... --device cuda --jobs 7
    python -m studies.peer_comparison table -o OUT

``train`` trains the model once per held-out recording on all the others, each fold in its
own process (``--set`` keys as `lidarflow train --set` takes them go to every run; a finished
run is kept). Models: ``flownet`` (``--recipe head``
on the flow network given by ``--flow-init``, trained on simulation only, so no fold sees its
held-out recording), ``head_only`` (the same head without the flow network, ``--recipe
head_only`` started from the fold's flownet run: train flownet first), ``sogmp`` and
``deeptracking`` (their own recipes). ``evaluate`` scores
each held-out recording with every fold model found, plus ``flownet_noflow`` (the flownet fold
model with its flow head set to zero: what the flow buys), with ``lidarflow evaluate --horizon
K``, K the recording's scans in about one second. Writes OUT/<model>/<recording>/run/ per
fold, OUT/evaluation/<recording>.json per held-out recording and, with ``table``,
OUT/peer_comparison.md and .json: per recording and on average, each method at k = 1 and K.
"""

from __future__ import annotations

import json
import multiprocessing
import os
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from studies.harness import (
    best_baselines,
    development,
    parse,
    parser,
    stem,
    write_atomic,
    write_json,
)

#: each model's recipe and the settings it starts from (``{flow_init}``: --flow-init;
#: ``{fold_flownet}``: the same fold's flownet run)
RECIPES: dict[str, tuple[str, dict[str, str]]] = {
    "flownet": ("head", {"model.init": "{flow_init}"}),
    # the same head without the flow network, from the fold's flownet head (fold-clean)
    "head_only": ("head_only", {"model.init": "{fold_flownet}"}),
    "sogmp": ("sogmp", {}),
    "deeptracking": ("paper", {"model.name": "deeptracking"}),
}
NOFLOW = "flownet_noflow"
BASELINES = ("copy_last", "temporal_average", "constant_velocity")
#: reported beside the others, never judged (it only moves the last map by the ego motion)
REFERENCES = ("copy_last_ego",)


def fold_run(out: Path, model: str, held: Path) -> Path:
    return out / model / stem(held) / "run"


def train_fold(
    out: Path,
    model: str,
    held: Path,
    recordings: Sequence[Path],
    flow_init: str,
    overrides: Sequence[str],
) -> str:
    """Train ``model`` on every recording but ``held`` (kept if already finished)."""
    from lidarflow.errors import LidarflowError
    from studies.folds import train_model

    run = fold_run(out, model, held)
    if (run / "model.safetensors").exists():
        return f"{model} without {stem(held)}: kept"
    fold_flownet = fold_run(out, "flownet", held)
    recipe, flags = RECIPES[model]
    if "{fold_flownet}" in flags.values() and not (fold_flownet / "model.safetensors").exists():
        return f"{model} without {stem(held)}: FAILED (train flownet first: {fold_flownet})"
    names = {"flow_init": flow_init, "fold_flownet": str(fold_flownet)}
    flags = {key: value.format(**names) for key, value in flags.items()}
    others = [r for r in recordings if r != held]
    try:
        train_model(others, run, recipe, [*overrides, "runtime.tensorboard=false"], flags)
    except LidarflowError as err:
        return f"{model} without {stem(held)}: FAILED ({err})"
    return f"{model} without {stem(held)}: done"


def zero_flow(run: Path, into: Path) -> Path:
    """A copy of the flownet run ``run`` with its flow head's weights and bias set to zero."""
    from safetensors.numpy import load_file, save_file

    into.mkdir(parents=True, exist_ok=True)
    weights = load_file(str(run / "model.safetensors"))
    zeroed = [k for k in weights if k.rsplit(".", 2)[-2:-1] == ["conv_flow"]]
    if not zeroed:
        raise SystemExit(f"{run}: no conv_flow weights to set to zero")
    for key in zeroed:
        weights[key][:] = 0
    save_file(weights, str(into / "model.safetensors"))
    (into / "model.json").write_text((run / "model.json").read_text())
    return into


def evaluate_fold(out: Path, held: Path, device: str, threads: int, horizon: int = 0) -> str:
    """Score every fold model of ``held`` found under ``out`` as `lidarflow evaluate` does,
    ``horizon`` steps ahead (0: about one second of ``held``)."""
    import torch

    from lidarflow.data import load_any
    from lidarflow.scan import GridSpec
    from studies.scoring import evaluate

    report = out / "evaluation" / f"{stem(held)}.json"
    if report.exists():
        return f"{stem(held)}: kept"
    models: dict[str, str] = {}
    for model in RECIPES:
        run = fold_run(out, model, held)
        if (run / "model.safetensors").exists():
            models[model] = str(run)
            if model == "flownet":
                models[NOFLOW] = str(zero_flow(run, run.parent / NOFLOW))
    if not models:
        return f"{stem(held)}: no fold model"
    # every fold model trains on the grid of the study's recordings
    grid = json.loads((Path(next(iter(models.values()))) / "model.json").read_text())["grid"]
    torch.set_num_threads(threads)
    recording = load_any(held)
    k = horizon or max(2, round(recording.frame_rate))
    scores = evaluate(
        [(str(held), recording)], models, grid=GridSpec(grid["height"], grid["width"], grid["res"]),
        horizon=k, device=device,
    )  # fmt: skip
    write_json(report, scores)
    return f"{stem(held)}: done"


def fold_scores(report: dict[str, Any], out: Path) -> dict[str, dict[str, float]]:
    """``{method: {f1_1, changed_f1_1, wmse_1, ssim_1, f1_K, ...}}`` of one held-out report."""
    entry = report["recordings"][0]
    names = {m: _model_of(m, report, out) for m in entry["horizon_f1"]}
    scores: dict[str, dict[str, float]] = {}
    for method, model in names.items():
        row = {}
        for key in ("f1", "changed_f1", "wmse", "ssim"):
            values = entry[f"horizon_{key}"][method]
            row[f"{key}_1"], row[f"{key}_K"] = values[0], values[-1]
        row["K"] = len(entry["horizon_f1"][method])
        scores[model] = row
    return scores


def _model_of(method: str, report: dict[str, Any], out: Path) -> str:
    """The table's name of a report's method: a baseline's own, a model's by its run folder."""
    if method in (NOFLOW, *RECIPES):  # the study's own reports name them so
        return method
    used = report["config"]["models"].get(method)
    if used is None:
        return method
    path = Path(used["weights_path"] if isinstance(used, dict) else used).resolve()
    for model in (NOFLOW, *RECIPES):
        if model in path.parts:
            return model
    return method


def verdict(model: dict[str, float], baselines: dict[str, dict[str, float]], k: str) -> str:
    """``wins`` when F1 beats the best baseline's and changed-cell F1 every baseline's, at
    horizon ``k`` (``"1"`` or ``"K"``)."""
    best, best_changed = best_baselines(
        {
            name: {"f1": b[f"f1_{k}"], "changed_f1": b[f"changed_f1_{k}"]}
            for name, b in baselines.items()
        }
    )
    f1_ok, changed_ok = model[f"f1_{k}"] > best, model[f"changed_f1_{k}"] > best_changed
    return (
        "wins"
        if f1_ok and changed_ok
        else "loses F1"
        if changed_ok
        else ("loses changed F1" if f1_ok else "loses both")
    )


def collect(out: Path, reports: Sequence[Path] = ()) -> dict[str, Any]:
    """Every scored fold under ``out`` (or the `lidarflow evaluate` ``reports`` given, named by
    their files): ``{"folds": {recording: {method: row}}, "mean": ...}``."""
    folds = {}
    for path in reports or sorted((out / "evaluation").glob("*.json")):
        folds[path.stem] = fold_scores(json.loads(path.read_text()), out)
    methods = sorted({m for f in folds.values() for m in f}, key=_order)
    mean = {}
    for method in methods:
        rows = [f[method] for f in folds.values() if method in f]
        if len(rows) == len(folds):
            mean[method] = {k: float(np.mean([r[k] for r in rows])) for k in rows[0] if k != "K"}
    wins = {
        method: {
            k: sum(
                verdict(f[method], {b: f[b] for b in BASELINES}, k) == "wins"
                for f in folds.values()
                if method in f
            )
            for k in ("1", "K")
        }
        for method in methods
        if method not in BASELINES + REFERENCES
    }
    params = {m: _parameters(out, m) for m in RECIPES}
    return {"folds": folds, "mean": mean, "wins": wins, "parameters": params}


def _order(method: str) -> tuple[int, str]:
    known = [*BASELINES, *REFERENCES, "flownet", NOFLOW, "head_only", "sogmp", "deeptracking"]
    return (known.index(method) if method in known else len(known), method)


def _parameters(out: Path, model: str) -> int | None:
    """The model's parameter count, as its first fold run's ``model.json`` records it."""
    for card in sorted(out.glob(f"{model}/*/run/model.json")):
        return int(json.loads(card.read_text())["parameters"])
    return None


def table(study: dict[str, Any]) -> str:
    """Markdown: per held-out recording and on average, every method at k = 1 and k = K."""
    head = (
        "| held-out | method | F1 k=1 | changed F1 k=1 | WMSE k=1 | SSIM k=1 | F1 ~1 s | "
        "changed F1 ~1 s | WMSE ~1 s | SSIM ~1 s | verdict k=1 / ~1 s |"
    )
    lines = [head, "|" + "---|" * 11]

    def row(where: str, method: str, r: dict[str, float], said: str) -> str:
        cells = [
            r[f"{key}_{k}"] for k in ("1", "K") for key in ("f1", "changed_f1", "wmse", "ssim")
        ]
        return f"| {where} | {method} | " + " | ".join(f"{c:.4f}" for c in cells) + f" | {said} |"

    for rec, fold in study["folds"].items():
        k = next(iter(fold.values()))["K"]
        baselines = {b: fold[b] for b in BASELINES}
        for method in sorted(fold, key=_order):
            said = (
                ""
                if method in BASELINES + REFERENCES
                else f"{verdict(fold[method], baselines, '1')} / "
                f"{verdict(fold[method], baselines, 'K')}"
            )
            lines.append(row(f"{rec} (K={k})", method, fold[method], said))
    for method, r in study["mean"].items():
        w = study["wins"].get(method)
        said = "" if w is None else f"wins {w['1']} / {w['K']} of {len(study['folds'])}"
        lines.append(row("**mean**", method, r, said))
    return "\n".join(lines) + "\n"


def _train_item(item: tuple) -> str:
    return train_fold(*item)


def _evaluate_item(item: tuple) -> str:
    return evaluate_fold(*item)


def _each(jobs: int, task: Any, items: Sequence[Any]) -> None:
    """``task`` on every item, ``jobs`` processes at a time (spawned: CUDA-safe), each outcome
    printed; exit 1 if any failed."""
    failed = 0
    with ProcessPoolExecutor(jobs, mp_context=multiprocessing.get_context("spawn")) as pool:
        for said in pool.map(task, items):
            print(said, flush=True)
            failed += "FAILED" in said
    if failed:
        raise SystemExit(f"{failed} of {len(items)} failed")


def main(argv: Sequence[str] | None = None) -> None:
    p = parser("peer_comparison", __doc__)
    p.add_argument("step", choices=("train", "evaluate", "table"))
    p.add_argument("--recordings", type=Path, nargs="+", default=development())
    p.add_argument("--model", choices=tuple(RECIPES), help="train: the model to train")
    p.add_argument("--flow-init", default="runs/sim_flow_2", help="flownet: the flow network")
    p.add_argument(
        "--set", dest="overrides", nargs="*", default=[], help="train: KEY=VALUE for every run"
    )
    p.add_argument("--held-out", type=Path, nargs="*", default=[], help="only these folds")
    p.add_argument("--jobs", type=int, default=1, help="folds at a time")
    p.add_argument("--device", default="cpu", help="evaluate: where the models run")
    p.add_argument("--threads", type=int, default=1, help="evaluate: CPU threads per fold")
    p.add_argument("--horizon", type=int, default=0, help="evaluate: K (0: scans in ~1 s)")
    p.add_argument(
        "--reports", type=Path, nargs="*", default=[], help="table: these reports, not OUT's"
    )
    args = parse(p, argv)
    out: Path = args.output
    held = args.held_out or args.recordings
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    if args.step == "train":
        if args.model is None:
            p.error("train needs --model")
        _each(
            args.jobs,
            _train_item,
            [(out, args.model, h, args.recordings, args.flow_init, args.overrides) for h in held],
        )
    elif args.step == "evaluate":
        items = [(out, h, args.device, args.threads, args.horizon) for h in held]
        _each(args.jobs, _evaluate_item, items)
    else:
        study = collect(out, args.reports)
        write_json(out / "peer_comparison.json", study)
        write_atomic(out / "peer_comparison.md", table(study))
        print(table(study))


if __name__ == "__main__":
    main()
