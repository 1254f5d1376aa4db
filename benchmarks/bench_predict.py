"""Scan-to-prediction latency of the streaming Predictor (rasterization included), per backend.

Single stream, the bundled model: median and p99 milliseconds per scan over a real recording's
scans, for the PyTorch eager backend (the reference, measured in the same run), onnxruntime
float32 and onnxruntime int8 (`lidarflow export --int8`, calibrated on the same sample; its
accuracy cost is measured on other recordings by `python -m studies.int8_accuracy`), each at
the given thread counts. Batched: scans/s for B streams stepped together (many robots at once).
An ego-motion model (the bundled one since v5) is given a pose with every scan, a slow drive
(5 cm and 0.5 degrees a scan), so every backend pays for the compensation as a robot with
odometry does (without a pose PyTorch skips it and the ONNX graph does not; the odometry check
is off, since the sample's sensor stands still and the check would drop that drive). These run
with fixed decision offsets; ``onnxruntime_fp32_online`` adds the offsets chosen online
(:mod:`lidarflow.predict.decision`, NumPy after the graph), its cost a ratio against the same
backend without it. Writes JSON
(default ``benchmarks/results/predict.json``).

    python benchmarks/bench_predict.py [--scans 200] [--threads 1 2] [--batch 32]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from _output import machine, write_json

from lidarflow.data import read_bag, sample_bag_path
from lidarflow.models.presets import resolve_model
from lidarflow.outputs.export import export_onnx
from lidarflow.outputs.quantize import quantize_onnx
from lidarflow.predict import Predictor
from lidarflow.predict.decision import DecisionPolicy
from lidarflow.scan import GridSpec, takes_subcell


def drive(n: int) -> np.ndarray:
    """``(n, 3)`` sensor poses of a slow drive: 5 cm forward and 0.5 degrees left a scan."""
    i = np.arange(n, dtype=np.float64)
    yaw = np.deg2rad(0.5) * i
    return np.stack([0.05 * np.cumsum(np.cos(yaw)), 0.05 * np.cumsum(np.sin(yaw)), yaw], axis=1)


def latency(predictor: Predictor, scans: list, warm: int = 10) -> dict[str, float]:
    poses = drive(len(scans)) if predictor.uses_motion else [None] * len(scans)
    for s, pose in zip(scans[:warm], poses[:warm], strict=True):
        predictor.update(s, pose)
    times = []
    for s, pose in zip(scans, poses, strict=True):
        t0 = time.perf_counter()
        predictor.update(s, pose)
        times.append(time.perf_counter() - t0)
    ms = np.array(times) * 1e3
    return {"median_ms": float(np.median(ms)), "p99_ms": float(np.percentile(ms, 99))}


def batched(
    model: torch.nn.Module, batch: int, steps: int, threads: int, device: str = "cpu"
) -> float:
    """Scans/s of ``batch`` streams stepped together; on CUDA in bf16 autocast, channels-last
    (the GPU path of training), synchronised before the clock is read."""
    torch.set_num_threads(threads)
    dev = torch.device(device)
    cuda = dev.type == "cuda"
    model = model.to(dev)
    channels = int(getattr(model, "input_channels", 2))  # (O, V) and v8's sub-cell maps
    x = (torch.rand(batch, channels, 100, 100, device=dev) > 0.9).float()
    if cuda:
        model = model.to(memory_format=torch.channels_last)
        x = x.contiguous(memory_format=torch.channels_last)
    state = model.init_state(batch, 100, 100, device=dev)
    # an ego-motion model compensates a motion as with odometry (1/2 cell, 0.5 degrees)
    ego = bool(getattr(model, "ego_motion", False))
    motion = (torch.tensor([[0.5, 0.0, 0.0087]], device=dev).expand(batch, 3),) if ego else ()
    with torch.inference_mode(), torch.autocast(dev.type, torch.bfloat16, enabled=cuda):
        for _ in range(3):
            out, state = model.step(x, state, *motion)
        if cuda:
            torch.cuda.synchronize()
        t0 = time.perf_counter()
        for _ in range(steps):
            out, state = model.step(x, state, *motion)
            model.predict_next(x, out)
        if cuda:
            torch.cuda.synchronize()
        return batch * steps / (time.perf_counter() - t0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scans", type=int, default=200)
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--batch", type=int, default=32)
    parser.add_argument(
        "--device",
        default="cpu",
        help="device of the batched measurement (cuda: bf16, e.g. "
        "--batch 4096); single-stream latency is always CPU",
    )
    parser.add_argument("--json", type=Path, default=Path("benchmarks/results/predict.json"))
    args = parser.parse_args()
    recording = read_bag(sample_bag_path())
    scans = [recording.scan(i % len(recording)) for i in range(args.scans)]
    results: dict[str, dict] = {}
    with tempfile.TemporaryDirectory() as tmp:
        net, card = resolve_model(None)
        net = net.eval()
        policy = DecisionPolicy.from_record(card["decision"])  # the bundled model's own
        onnx_path = export_onnx(net, Path(tmp) / "m.onnx", decision=policy)
        maps = recording.stacked_maps(GridSpec(), subcell=takes_subcell(net.input_channels))
        int8_path = quantize_onnx(onnx_path, Path(tmp) / "m8.onnx", maps)
        for threads in args.threads:
            torch.set_num_threads(threads)
            fixed = {"threads": threads, "check_odometry": False, "online_decision": False}
            ref = latency(Predictor(None, **fixed), scans)
            ort = latency(Predictor(onnx_path, **fixed), scans)
            ort8 = latency(Predictor(int8_path, **fixed), scans)
            online = {**fixed, "online_decision": True}
            ort_online = latency(Predictor(onnx_path, **online), scans)
            results[f"threads={threads}"] = {
                "torch_eager_fp32": ref,
                "onnxruntime_fp32": ort,
                "onnxruntime_int8": ort8,
                "onnxruntime_fp32_online": ort_online,
                "online_decision_cost_vs_fixed": ort_online["median_ms"] / ort["median_ms"],
                "onnxruntime_speedup_vs_torch": ref["median_ms"] / ort["median_ms"],
                "onnxruntime_int8_speedup_vs_torch": ref["median_ms"] / ort8["median_ms"],
            }
            print(
                f"threads={threads}: torch {ref['median_ms']:.2f} ms (p99 {ref['p99_ms']:.2f}), "
                f"onnxruntime {ort['median_ms']:.2f} ms (p99 {ort['p99_ms']:.2f}), "
                f"int8 {ort8['median_ms']:.2f} ms (p99 {ort8['p99_ms']:.2f}), "
                f"onnxruntime with the online decision {ort_online['median_ms']:.2f} ms"
            )
        steps = 5 if args.device == "cpu" else 50
        rate = batched(net, args.batch, steps, max(args.threads), args.device)
        results["batched"] = {"batch": args.batch, "device": args.device, "torch_scans_per_s": rate}
        print(f"batched B={args.batch} on {args.device}: {rate:,.0f} scans/s (torch)")
    out = {
        "benchmark": "predict",
        "scans": args.scans,
        "model": "bundled",
        "machine": machine(),
        "note": "latency includes rasterization; absolute times are indicative on a shared CPU",
        "results": results,
    }
    write_json(args.json, out)


if __name__ == "__main__":
    main()
