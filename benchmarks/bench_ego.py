"""What ego-motion compensation costs: one streaming step and one training step (forward +
backward + loss) of LiDAR-FlowNet with and without :class:`EgoCompensated`, same weights, same
data, measured in the same run (the plain model is the reference; report the ratio).

Writes JSON (default ``benchmarks/results/ego.json``).

    python benchmarks/bench_ego.py [--size 100] [--batch 4] [--time-steps 12] [--threads 1]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch
from _output import machine, write_json

from lidarflow.losses import LossConfig, flow_loss
from lidarflow.models import build_model


def _median_seconds(fn, repeats: int) -> float:
    fn()  # warm-up (allocator, oneDNN primitives)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=100)
    parser.add_argument("--batch", type=int, default=4)
    parser.add_argument("--time-steps", type=int, default=12)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--json", type=Path, default=Path("benchmarks/results/ego.json"))
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    plain = build_model("flownet", zero_init_flow=False)
    ego = build_model("flownet", ego_motion=True, zero_init_flow=False)
    ego.inner.load_state_dict(plain.state_dict())
    n, b, t = args.size, args.batch, args.time_steps
    g = torch.Generator().manual_seed(1)
    seq = (torch.rand(b, t, 2, n, n, generator=g) > 0.9).float()
    motions = torch.randn(b, t, 3, generator=g) * torch.tensor([2.0, 0.5, 0.05])
    x, m = seq[:1, 0], motions[:1, 0]

    def stream(model, with_motion):
        state = model.init_state(1, n, n)

        def run():
            with torch.inference_mode():
                out, _ = model.step(x, state, m) if with_motion else model.step(x, state)
                model.predict_next(x, out)

        return run

    def train_step(model, with_motion):
        loss_cfg = LossConfig.blurred_both()

        def run():
            out, _ = model(seq, None, motions) if with_motion else model(seq)
            flow_loss(seq, out, 3, loss_cfg, warmup=t // 2).backward()

        return run

    step_plain = _median_seconds(stream(plain, False), args.repeats * 10)
    step_ego = _median_seconds(stream(ego, True), args.repeats * 10)
    train_plain = _median_seconds(train_step(plain, False), args.repeats)
    train_ego = _median_seconds(train_step(ego, True), args.repeats)
    results = {
        "stream_step_ms": {"plain": step_plain * 1e3, "ego": step_ego * 1e3},
        "stream_step_ratio_ego_to_plain": step_ego / step_plain,
        "train_frame_steps_per_s": {"plain": b * t / train_plain, "ego": b * t / train_ego},
        "train_ratio_ego_to_plain": train_ego / train_plain,
    }
    print(
        f"stream step {n}x{n}: plain {step_plain * 1e3:.2f} ms, ego {step_ego * 1e3:.2f} ms "
        f"(x{step_ego / step_plain:.2f}); training B={b} T={t}: plain {b * t / train_plain:.1f}, "
        f"ego {b * t / train_ego:.1f} frame-steps/s (x{train_ego / train_plain:.2f} time)"
    )
    out = {
        "benchmark": "ego_motion_overhead",
        "config": vars(args) | {"json": str(args.json)},
        "machine": machine(),
        "note": "shared 2-core CPU: compare the ratios (same run), not absolute times",
        "results": results,
    }
    write_json(args.json, out)


if __name__ == "__main__":
    main()
