"""Choose the moving-segmentation threshold on simulated *tuning* recordings (issue 8).

Runs a flow model (default: the bundled one) over each recording, streaming with 10 warm-up
frames, and scores :func:`lidarflow.predict.moving.moving_mask` against the simulator's ``moving``
ground truth for a sweep of thresholds, with and without background-motion compensation. The
same sweep on the ground-truth forward flow is the upper bound of the rule itself. Writes JSON.

Use recordings that are NOT the evaluation ones (the README numbers are on seed 7):

    lidarflow simulate -s dynamic --frames 600 --seed 3 -o /tmp/seg/tune_dyn3.npz
    lidarflow simulate -s static --frames 600 --seed 3 -o /tmp/seg/tune_static3.npz
    python benchmarks/seg_threshold.py /tmp/seg/tune_dyn3.npz /tmp/seg/tune_static3.npz \
        -o benchmarks/results/seg_threshold.json
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch

from lidarflow.data import load_any
from lidarflow.evaluate.metrics import Counts, confusion
from lidarflow.evaluate.model_method import ModelMethod
from lidarflow.models.presets import resolve_model
from lidarflow.predict.moving import moving_mask
from lidarflow.scan import GridSpec
from lidarflow.sim.storage import dense_flow

THRESHOLDS = (0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 1.0, 1.2, 1.5)


def sweep(paths: list[str], model: str | None, warmup: int = 10) -> dict:
    net, card = resolve_model(model)
    stream = ModelMethod("model", net, online=False)
    grid = GridSpec()
    keys = [(src, comp, th) for src in ("model", "ground_truth") for comp in (True, False)
            for th in THRESHOLDS]
    totals = {k: Counts() for k in keys}
    frames = 0
    for path in paths:
        recording = load_any(path)
        occupancy, visibility = recording.maps(grid)
        truth = recording.extras["moving"]
        stream.reset()
        for t in range(len(recording) - 1):
            stream.update(occupancy[t], visibility[t])
            if t < warmup:
                continue
            frames += 1
            gt = truth[t] & occupancy[t]
            flows = {"model": stream.forward_flow, "ground_truth": dense_flow(recording, t)[1]}
            for src, comp, th in keys:
                mask = moving_mask(occupancy[t], flows[src], th, comp)
                totals[src, comp, th] = totals[src, comp, th] + confusion(mask, gt)
    rows = [
        {"flow": src, "compensate": comp, "threshold": th, "iou": c.iou,
         "precision": c.precision, "recall": c.recall}
        for (src, comp, th), c in totals.items()
    ]
    best = max((r for r in rows if r["flow"] == "model"), key=lambda r: r["iou"])
    return {
        "command": "python " + " ".join(sys.argv),
        "recordings": paths,
        "model": card.get("weights_path"),
        "frames_scored": frames,
        "best_for_model": best,
        "rows": rows,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recordings", nargs="+", help="simulated recordings (.npz) to tune on")
    parser.add_argument("--model", default=None, help="run folder / weights (default: bundled)")
    parser.add_argument("-o", "--output", type=Path, default=Path("seg_threshold.json"))
    args = parser.parse_args()
    torch.set_num_threads(1)
    result = sweep(args.recordings, args.model)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(result, indent=2))
    for r in result["rows"]:
        print(f"{r['flow']:>12} comp={r['compensate']!s:<5} th={r['threshold']:<4} "
              f"iou={r['iou']:.3f} p={r['precision']:.3f} r={r['recall']:.3f}")
    print("best (model):", result["best_for_model"])
    np.set_printoptions(precision=3)


if __name__ == "__main__":
    main()
