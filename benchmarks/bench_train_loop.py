"""Throughput of the whole training loop (`lidarflow.train.train`), written as JSON.

Unlike ``bench_train_step.py`` (one model step in isolation), this runs real epochs: the
DataLoader over recording windows, the optimiser step, the divergence checks, validation and the
per-epoch checkpoint, so the gap between the two is the loop's overhead. The figure is the
loop's own ``frame_steps_per_s`` (B x T frame-steps per batch over the epoch's training time,
validation excluded) of the last epoch; every variant runs in the same process, the plain eager
fp32 one first, so ratios survive a noisy, shared machine.

Data: a synthetic recording (a wall and an object moving one cell per frame) on the paper's
100 x 100 grid, windows of T frames.

Example (the paper's shapes; a few minutes on a shared 2-core CPU):
    PYTHONPATH=src:. python benchmarks/bench_train_loop.py --batch 32 --seq-len 20 \
        --windows 64 --variants eager bf16+cl -o bench_train_loop.json
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import tempfile
import time
from pathlib import Path

import torch

from lidarflow.data import Recording
from lidarflow.models.speed import native_bf16
from lidarflow.scan import BeamGeometry, Scan
from lidarflow.train import build_config, train

VARIANTS = {
    "eager": {},
    "cl": {"runtime.channels_last": True},
    "bf16": {"runtime.amp": "bf16"},
    "bf16+cl": {"runtime.amp": "bf16", "runtime.channels_last": True},
    "bf16+cl+compile": {
        "runtime.amp": "bf16",
        "runtime.channels_last": True,
        "runtime.compile": "cells",
    },
}


def moving_recording(frames: int, beams: int = 541) -> Recording:
    """A wall at 8 m and a 0.6 m object at 4 m crossing sideways by 0.1 m (one cell) a frame."""
    geom = BeamGeometry(beams, -torch.pi / 2, torch.pi / (beams - 1), 0.05, 12.0)
    angles = geom.angle_min + geom.angle_increment * torch.arange(beams, dtype=torch.float64)
    scans = []
    y = 3.0
    for i in range(frames):
        r = torch.where(torch.cos(angles) > 0.05, 8.0 / torch.cos(angles), torch.inf)
        lo, hi = torch.atan2(torch.tensor(y - 0.3), torch.tensor(4.0)), torch.atan2(
            torch.tensor(y + 0.3), torch.tensor(4.0)
        )
        hit = (angles >= lo) & (angles <= hi)
        r = torch.where(hit, 4.0 / torch.cos(angles), r)
        scans.append(Scan(r.float().numpy(), geom, int(1e9 + i * 1e8)))
        y = y - 0.1 if y > -3.0 else 3.0
    return Recording.from_scans(scans, meta={"source": "bench"})


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, default=32)
    parser.add_argument("--seq-len", type=int, default=20)
    parser.add_argument("--windows", type=int, default=64, help="training windows per epoch")
    parser.add_argument("--epochs", type=int, default=2, help="the last one is reported")
    parser.add_argument("--variants", nargs="+", default=["eager", "bf16+cl"], choices=VARIANTS)
    parser.add_argument("--threads", type=int, default=0)
    parser.add_argument("-o", "--output", type=Path, default=Path("bench_train_loop.json"))
    args = parser.parse_args()

    tmp = Path(tempfile.mkdtemp(prefix="bench_train_loop_"))
    frames = args.windows * args.seq_len + 2 * args.seq_len  # + a validation tail
    source = moving_recording(frames).save(tmp / "moving.npz")
    results = []
    for name in args.variants:
        flags = {
            "data.sources": [str(source)],
            "data.seq_len": args.seq_len,
            "data.warmup": min(10, args.seq_len // 2),
            "data.val_fraction": 1.5 * args.seq_len / frames,
            "optim.batch_size": args.batch,
            "optim.epochs": args.epochs,
            "runtime.threads": args.threads,
            "runtime.eval_before_training": False,
            "runtime.tensorboard": False,
            **VARIANTS[name],
        }
        t0 = time.perf_counter()
        result = train(build_config("paper", None, flags), tmp / name)
        row = result.rows[-1]
        results.append(
            {
                "variant": name,
                "frame_steps_per_s": row["frame_steps_per_s"],
                "train_loss": row["train_loss"],
                "wall_s": time.perf_counter() - t0,
            }
        )
        print(f"{name}: {row['frame_steps_per_s']:.1f} frame-steps/s")
    device = torch.device("cuda" if torch.cuda.is_available() else "cpu")
    reference = results[0]["frame_steps_per_s"]
    for r in results:
        r["ratio_to_first"] = r["frame_steps_per_s"] / reference
    report = {
        "benchmark": "train_loop",
        "batch": args.batch,
        "seq_len": args.seq_len,
        "grid": 100,
        "windows_per_epoch": args.windows,
        "threads": torch.get_num_threads(),
        "cpu_count": os.cpu_count(),
        "device": device.type,
        # Without native bf16 (an AVX2-only CPU) bf16 autocast is emulated: read its ratio so.
        "native_bf16": native_bf16(device),
        "cpu_capability": torch.backends.cpu.get_cpu_capability(),
        "torch": torch.__version__,
        "python": platform.python_version(),
        "note": "shared machine: compare ratios within this run, not absolute figures",
        "results": results,
    }
    args.output.write_text(json.dumps(report, indent=2) + "\n")
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
