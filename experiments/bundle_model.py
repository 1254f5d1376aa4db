"""Ship a trained run as the bundled default model, with its model card.

Copies the run's ``model.safetensors`` and ``model.json`` into ``src/lidarflow/assets/model/``,
evaluates it (streaming, beside the baselines) on held-out recordings it never trained on, and
writes ``MODEL_CARD.md`` (data, configuration, commit, training curve, held-out results with
wins and losses stated) plus ``heldout.json``. Prints the SHA-256 to record in
``lidarflow.models.presets.BUNDLED``.

    python experiments/bundle_model.py RUN_DIR --heldout A.bag B.bag ... [--out DIR]
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
from pathlib import Path

from lidarflow.data import load_any
from lidarflow.evaluate.ego import CopyLastEgo
from lidarflow.evaluate.model_method import ModelMethod
from lidarflow.evaluate.report import against_baselines
from lidarflow.models import uses_ego_motion
from lidarflow.models.weights import load_trained, sha256
from lidarflow.predict.baselines import ConstantVelocity, CopyLast, TemporalAverage
from lidarflow.scan import GridSpec
from lidarflow.viz.evaluation import evaluate_and_report


def commit(run: Path | None = None) -> str:
    """The commit the run trained at (its run.json), else the checkout's HEAD."""
    record = run / "run.json" if run is not None else None
    if record is not None and record.exists():
        trained_at = json.loads(record.read_text()).get("commit")
        if trained_at:
            return str(trained_at)
    try:
        out = subprocess.run(
            ["git", "rev-parse", "HEAD"], capture_output=True, text=True, check=True
        )
        return out.stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def verdict(methods: dict[str, dict[str, float]]) -> str:
    v = against_baselines(methods)["bundled"]
    if v["wins"]:
        return "wins (F1 and changed-cell F1 above every baseline)"
    best_f1 = methods[v["f1_baseline"]]["f1"]
    best_changed = methods[v["changed_f1_baseline"]]["changed_f1"]
    parts = [
        f"F1 {'above' if v['f1_margin'] > 0 else 'below'} the best baseline ({best_f1:.3f})",
        f"changed-cell F1 {'above' if v['changed_f1_margin'] > 0 else 'below'} the best baseline "
        f"({best_changed:.3f})",
    ]
    return "does not win: " + "; ".join(parts)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path)
    parser.add_argument("--heldout", type=Path, nargs="+", required=True)
    parser.add_argument("--out", type=Path, default=Path("src/lidarflow/assets/model"))
    parser.add_argument("--command", default="", help="the training command, for the card")
    args = parser.parse_args()
    net, card = load_trained(args.run)
    args.out.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(args.run / "model.safetensors", args.out / "model.safetensors")
    shutil.copyfile(args.run / "model.json", args.out / "model.json")
    methods = [CopyLast(), TemporalAverage(), ConstantVelocity()]
    if uses_ego_motion(net):  # a reference beside it, not a baseline of the verdict
        methods.append(CopyLastEgo())
    methods.append(ModelMethod("bundled", net))
    if methods[-1].online is not None:  # the same weights with the fixed offsets, beside
        methods.append(ModelMethod("bundled_fixed", net, online=False))
    named = [(p.name, load_any(p)) for p in args.heldout]
    report = evaluate_and_report(named, methods, GridSpec(), 10, {"model": str(args.run)})
    (args.out / "heldout.json").write_text(json.dumps(report, indent=2))
    rows = [json.loads(line) for line in (args.run / "metrics.jsonl").read_text().splitlines()]
    config = json.loads((args.run / "config.json").read_text())
    lines = [
        "# Model card: the bundled LiDAR-FlowNet",
        "",
        f"- Weights: `model.safetensors`, SHA-256 `{sha256(args.out / 'model.safetensors')}`",
        f"- Architecture: {card['model']} (Table I), {card.get('parameters', '?')} parameters, "
        f"grid {card.get('grid')}",
        f"- Trained by lidarflow's own `train` command at commit `{commit(args.run)}`, on the "
        "CPU of a 2-core machine; recipe "
        f"`{config.get('recipe')}`, {len(rows) - 1} epochs.",
        f"- Training data: {', '.join(Path(s).name for s in config['data']['sources'])}",
        f"- Command: `{args.command}`" if args.command else "",
        "",
        "## Training curve (validation: the last 10 % of each training recording)",
        "",
        "| epoch | val loss | val F1 | copy-last F1 | changed-cell F1 | EPE | zero-flow EPE |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['epoch']} | {r.get('val_loss', float('nan')):.6f} | {r.get('val_f1', 0):.4f} | "
            f"{r.get('val_copy_last_f1', 0):.4f} | {r.get('val_changed_f1', 0):.4f} | "
            f"{r.get('val_epe', float('nan')):.3f} | {r.get('val_epe_zero', float('nan')):.3f} |"
        )
    lines += [
        "",
        "## Held-out recordings (never trained on), streaming, 10 warm-up frames",
        "",
        "| recording | method | F1 | precision | recall | AP | changed-cell F1 |",
        "|---|---|---|---|---|---|---|",
    ]
    for entry in report["recordings"]:
        for name, m in entry["methods"].items():
            lines.append(
                f"| {entry['path']} | {name} | {m['f1']:.4f} | {m['precision']:.4f} | "
                f"{m['recall']:.4f} | {m['ap']:.4f} | {m['changed_f1']:.4f} |"
            )
    lines += [
        "",
        "Verdict per recording (a model wins when both its F1 and its changed-cell F1 "
        "are above every baseline's):",
        "",
    ]
    for entry in report["recordings"]:
        lines.append(f"- {entry['path']}: {verdict(entry['methods'])}")
    lines.append(f"- overall (micro-averaged): {verdict(report['overall'])}")
    (args.out / "MODEL_CARD.md").write_text(
        "\n".join(line for line in lines if line is not None) + "\n"
    )
    print("\n".join(lines))
    print(f"\nweights sha256: {sha256(args.out / 'model.safetensors')}")


if __name__ == "__main__":
    main()
