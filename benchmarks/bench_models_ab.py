"""Does one model cost more per scan than another? Alternating rounds in one run.

On a shared machine absolute times drift by 2-3x between runs (the bundled model's PyTorch step
measured 10.7 ms one day and 19-23 ms another), so two models are compared in the same run,
round by round: each round streams the same scans of the sample through a fresh ``Predictor``
of each model in turn (PyTorch eager, no poses, so the motion from the scans is included), and
the result is the median over rounds of the per-round ratio of median step times.

    python benchmarks/bench_models_ab.py RUN_A bundled [--rounds 6] [--scans 120] [--threads 1]

(the v6 / v8 comparison in ``benchmarks/results/models_ab_v8.json`` took v6's weights, since
left the tree: ``git show a4a22da:docs/results/accuracy/bundled_v6/model.safetensors``).

Writes JSON (default ``benchmarks/results/models_ab.json``).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch
from _output import machine, write_json

from lidarflow.data import load_any, sample_bag_path
from lidarflow.predict import Predictor

WARMUP_SCANS = 20  # the first steps allocate and fill the memories


def step_times_ms(model: str, scans: list) -> np.ndarray:
    """Milliseconds of each ``Predictor.update`` of a fresh predictor of ``model``."""
    predictor = Predictor(model)  # "bundled" resolves like any other name
    times = []
    for scan in scans:
        start = time.perf_counter()
        predictor.update(scan)
        times.append(time.perf_counter() - start)
    return np.array(times[WARMUP_SCANS:]) * 1e3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("reference", help="run folder, ONNX file or 'bundled'")
    parser.add_argument("model", help="the model compared with it")
    parser.add_argument("--rounds", type=int, default=6)
    parser.add_argument("--scans", type=int, default=120)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--json", type=Path, default=Path("benchmarks/results/models_ab.json"))
    args = parser.parse_args()
    if args.scans <= WARMUP_SCANS:
        parser.error(f"--scans must be above the {WARMUP_SCANS} warm-up scans")
    torch.set_num_threads(args.threads)
    recording = load_any(sample_bag_path())
    scans = [recording.scan(i) for i in range(min(args.scans, len(recording)))]
    medians: dict[str, list[float]] = {args.reference: [], args.model: []}
    for _ in range(args.rounds):
        for name in medians:
            medians[name].append(float(np.median(step_times_ms(name, scans))))
    ratios = np.array(medians[args.model]) / np.array(medians[args.reference])
    ratio = float(np.median(ratios))
    print(f"{args.model} / {args.reference}: {ratio:.3f} (per round {np.round(ratios, 3)})")
    write_json(
        args.json,
        {
            "benchmark": "models_ab",
            "reference": args.reference,
            "model": args.model,
            "threads": args.threads,
            "scans": len(scans),
            "warmup_scans": WARMUP_SCANS,
            "machine": machine(),
            "median_step_ms_per_round": medians,
            "ratio_model_over_reference": ratio,
            "note": "absolute times are indicative only; compare the ratio",
        },
    )


if __name__ == "__main__":
    main()
