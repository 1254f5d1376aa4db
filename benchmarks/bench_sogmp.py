"""What SOGMP costs beside the bundled model: parameters, and the model's step alone per scan.

One stream, 1 thread by default: the step of each model (PyTorch eager, and onnxruntime on
its ``lidarflow export``), on the sample's maps, rasterization and motion left out (the whole
``Predictor.update`` per scan is ``bench_models_ab.py``'s). Absolute times drift 2-3x on a
shared machine, so the two models alternate round by round and the result is the median over
rounds of the per-round ratio of median step times. Each model gets a small motion with every
step (half a cell, 0.5 degrees), as with odometry, so both pay for their compensation.

    python benchmarks/bench_sogmp.py RUN [--rounds 5] [--steps 40] [--threads 1]

Writes JSON (default ``benchmarks/results/sogmp.json``).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from _output import machine, write_json

from lidarflow.data import load_any, sample_bag_path
from lidarflow.models import count_parameters
from lidarflow.models.presets import resolve_model
from lidarflow.outputs.export import export_onnx
from lidarflow.predict.backends import OnnxBackend, TorchBackend
from lidarflow.predict.step import StepInputs
from lidarflow.scan import GridSpec, takes_subcell

MOTION = np.array([0.5, 0.0, 0.0087], np.float32)


def step_ms(backend: TorchBackend | OnnxBackend, maps: np.ndarray, warm: int = 3) -> float:
    """Median milliseconds of one step over ``maps`` ``(N, C, H, W)``."""
    state = backend.init_state(*maps.shape[-2:])
    times = []
    for i, frame in enumerate(maps):
        start = time.perf_counter()
        _, _, state = backend.run(StepInputs(frame[None], MOTION), state)
        if i >= warm:
            times.append(time.perf_counter() - start)
    return float(np.median(times) * 1e3)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("model", help="a SOGMP run folder (its weights do not change the time)")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--steps", type=int, default=40)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--json", type=Path, default=Path("benchmarks/results/sogmp.json"))
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    recording = load_any(sample_bag_path())
    results: dict[str, dict] = {}
    medians: dict[str, dict[str, list[float]]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        backends = {}
        for name in ("bundled", args.model):
            net, _ = resolve_model(name)
            subcell = takes_subcell(net.input_channels)
            maps = recording.stacked_maps(GridSpec(), stop=args.steps, subcell=subcell)
            onnx = export_onnx(net, Path(tmp) / f"{len(backends)}.onnx")
            backends[name] = (
                maps.astype(np.float32),
                TorchBackend(net, threads=args.threads),
                OnnxBackend(onnx, threads=args.threads),
            )
            results[name] = {"parameters": count_parameters(net)}
            medians[name] = {"torch": [], "onnxruntime": []}
        for _ in range(args.rounds):
            for name, (maps, eager, ort) in backends.items():
                medians[name]["torch"].append(step_ms(eager, maps))
                medians[name]["onnxruntime"].append(step_ms(ort, maps))
    ratios = {}
    for backend in ("torch", "onnxruntime"):
        per_round = np.array(medians[args.model][backend]) / np.array(medians["bundled"][backend])
        ratios[backend] = float(np.median(per_round))
        print(f"{backend}: {args.model} / bundled per step {ratios[backend]:.1f}x")
    print(f"parameters: {results[args.model]['parameters']} / {results['bundled']['parameters']}")
    write_json(
        args.json,
        {
            "benchmark": "sogmp",
            "model": args.model,
            "threads": args.threads,
            "steps": args.steps,
            "machine": machine(),
            "parameters": {k: v["parameters"] for k, v in results.items()},
            "median_step_ms_per_round": medians,
            "ratio_over_bundled": ratios,
            "note": "model step only (no rasterization, no motion estimation); compare ratios",
        },
    )


if __name__ == "__main__":
    main()
