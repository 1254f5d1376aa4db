"""Training throughput of LiDAR-FlowNet: frame-steps per second, written as JSON.

A frame-step is one frame through forward and backward, loss included: one iteration of a
(B, T) batch counts B x T frame-steps (the paper's recipe: B = 32, T = 20, 100 x 100 grid, the
loss on the last T - 11 pairs). The optimiser step is left out (42.5 K parameters: negligible).

Variants, each measured in the same run as the reference so that ratios survive a noisy,
shared machine:
- ``reference``: plain eager fp32 LiDAR-FlowNet written here, six separate convolutions per
  GRU as in the paper's equations, NCHW. Measured first and last; ratios use the mean.
- the project's model (fused gate convolutions) with any of the options, joined by ``+``:
  ``cl`` (channels-last), ``bf16`` (CPU/GPU autocast), ``compile-cells`` or ``compile-step``
  (torch.compile; the first, untimed iteration pays the compilation).

Example (short, for a shared 2-core CPU):
    PYTHONPATH=src python benchmarks/bench_train_step.py --batch 16 --time-steps 12 --iters 2 \
        --variants fused+cl+bf16 fused+cl+bf16+compile-step -o train_step.json
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import platform
import statistics
import time
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from lidarflow.losses import LossConfig, flow_loss
from lidarflow.models import build_model
from lidarflow.models.speed import accelerate

OPTIONS = {"cl", "bf16", "compile-cells", "compile-step"}
DEFAULT_VARIANTS = (
    "fused",
    "fused+cl",
    "fused+cl+bf16",
    "fused+cl+compile-step",
    "fused+cl+bf16+compile-step",
)


class ReferenceGRU(nn.Module):
    """The paper's ConvGRU, literally: six convolutions, biases on the x-side (42,500 total)."""

    def __init__(self, channels: int, dilation: int) -> None:
        super().__init__()

        def conv(bias: bool) -> nn.Conv2d:
            return nn.Conv2d(channels, channels, 3, padding=dilation, dilation=dilation, bias=bias)

        self.w_xf, self.w_xr, self.w_xy = conv(True), conv(True), conv(True)
        self.w_yf, self.w_yr, self.w_yy = conv(False), conv(False), conv(False)

    def forward(self, x: Tensor, y: Tensor) -> Tensor:
        f = torch.sigmoid(self.w_xf(x) + self.w_yf(y))
        r = torch.sigmoid(self.w_xr(x) + self.w_yr(y))
        ybar = torch.tanh(self.w_xy(x) + r * self.w_yy(y))
        return f * y + (1 - f) * ybar


class ReferenceFlowNet(nn.Module):
    """Table I in plain eager PyTorch: the reference every speed-up is measured against."""

    def __init__(self) -> None:
        super().__init__()
        self.conv0 = nn.Conv2d(2, 16, 3, padding=1)
        self.grus = nn.ModuleList(ReferenceGRU(16, d) for d in (1, 2, 4))
        self.conv_flow = nn.Conv2d(16, 4, 3, padding=1)
        nn.init.zeros_(self.conv_flow.weight)
        nn.init.zeros_(self.conv_flow.bias)

    def forward(self, seq: Tensor) -> Tensor:
        b, t, _, h, w = seq.shape
        state = [seq.new_zeros(b, 16, h, w) for _ in self.grus]
        outs = []
        for i in range(t):
            x = F.relu(self.conv0(seq[:, i]))
            for j, gru in enumerate(self.grus):
                x = state[j] = gru(x, state[j])
            outs.append(self.conv_flow(x))
        return torch.stack(outs, dim=1)


def _make_variant(name: str, device: torch.device) -> tuple[nn.Module, bool]:
    """Build a variant; returns the module (called as ``module(seq) -> flows``) and bf16 flag."""
    if name == "reference":
        return ReferenceFlowNet().to(device), False
    tokens = name.split("+")
    if tokens[0] != "fused" or not set(tokens[1:]) <= OPTIONS:
        options = "][+".join(sorted(OPTIONS))
        raise SystemExit(f"unknown variant {name!r}: 'reference' or 'fused[+{options}]'")
    compile_mode = "none"
    if "compile-cells" in tokens:
        compile_mode = "cells"
    if "compile-step" in tokens:
        compile_mode = "step"
    model = build_model("flownet").to(device)
    accelerate(model, channels_last="cl" in tokens, compile=compile_mode)  # type: ignore[arg-type]

    class _Flows(nn.Module):
        def __init__(self, inner: nn.Module) -> None:
            super().__init__()
            self.inner = inner

        def forward(self, seq: Tensor) -> Tensor:
            return self.inner(seq)[0]

    return _Flows(model), "bf16" in tokens


def _measure(
    name: str, seq: Tensor, iters: int, warmup_iters: int, kernel_size: int, warmup: int
) -> dict[str, object]:
    torch.manual_seed(0)
    module, bf16 = _make_variant(name, seq.device)
    config = LossConfig.paper()

    def one_step() -> float:
        ctx = (
            torch.autocast(seq.device.type, dtype=torch.bfloat16)
            if bf16
            else contextlib.nullcontext()
        )
        module.zero_grad(set_to_none=True)
        with ctx:
            flows = module(seq)
            loss = flow_loss(seq, flows, kernel_size, config, warmup=warmup)
        loss.backward()
        if seq.device.type == "cuda":
            torch.cuda.synchronize()
        return float(loss.detach())

    t0 = time.perf_counter()
    for _ in range(warmup_iters):
        one_step()
    first_s = time.perf_counter() - t0
    times, cpu_times = [], []
    for _ in range(iters):
        t0, c0 = time.perf_counter(), time.process_time()
        one_step()
        times.append(time.perf_counter() - t0)
        cpu_times.append(time.process_time() - c0)
    frames = seq.shape[0] * seq.shape[1]
    med = statistics.median(times)
    return {
        "variant": name,
        "frame_steps_per_s": frames / med,
        "best_frame_steps_per_s": frames / min(times),
        "seconds_per_iter": times,
        # CPU seconds of this process (all threads): less sensitive to other users of a shared
        # machine than wall time, though spinning worker threads inflate it.
        "cpu_seconds_per_iter": cpu_times,
        "warmup_seconds": first_s,
    }


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--batch", type=int, default=32, help="sequences per batch (paper: 32)")
    parser.add_argument("--time-steps", type=int, default=20, help="frames per sequence (paper 20)")
    parser.add_argument("--size", type=int, default=100, help="grid cells per side (paper: 100)")
    parser.add_argument("--iters", type=int, default=2, help="timed iterations per variant")
    parser.add_argument("--warmup-iters", type=int, default=1, help="untimed iterations first")
    parser.add_argument("--kernel-size", type=int, default=9, help="Gaussian filter size")
    parser.add_argument("--threads", type=int, default=0, help="torch threads (0: leave default)")
    parser.add_argument("--device", default="cpu", help="cpu or cuda")
    parser.add_argument("--variants", nargs="+", default=list(DEFAULT_VARIANTS))
    parser.add_argument("-o", "--output", type=Path, default=Path("bench_train_step.json"))
    args = parser.parse_args()

    if args.threads > 0:
        torch.set_num_threads(args.threads)
    device = torch.device(args.device)
    warmup = min(10, args.time_steps - 2)
    gen = torch.Generator().manual_seed(0)
    size = (args.batch, args.time_steps, 1, args.size, args.size)
    occ = (torch.rand(size, generator=gen) > 0.97).float()
    vis = torch.maximum(occ, (torch.rand(size, generator=gen) > 0.4).float())
    seq = torch.cat([occ, vis], dim=2).to(device)

    def measure(name: str) -> dict[str, object]:
        result = _measure(name, seq, args.iters, args.warmup_iters, args.kernel_size, warmup)
        print(f"{name}: {result['frame_steps_per_s']:.1f} frame-steps/s", flush=True)
        return result

    load_before = os.getloadavg()
    results = [measure("reference")]
    results += [measure(name) for name in args.variants]
    results.append(measure("reference"))
    ref = statistics.mean([results[0]["frame_steps_per_s"], results[-1]["frame_steps_per_s"]])
    for r in results:
        r["ratio_to_reference"] = r["frame_steps_per_s"] / ref
    report = {
        "benchmark": "train_step",
        "unit": "frame-steps/s (one frame through forward + backward, loss included)",
        "config": {
            **{k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()},
            "loss": "LossConfig.paper()",
            "warmup_frames": warmup,
        },
        "reference_frame_steps_per_s": ref,
        "results": results,
        "environment": {
            "torch": torch.__version__,
            "device": torch.cuda.get_device_name()
            if device.type == "cuda"
            else (platform.processor() or platform.machine()),
            "cpu_count": os.cpu_count(),
            "torch_threads": torch.get_num_threads(),
            "loadavg_before": load_before,
            "loadavg_after": os.getloadavg(),
            "note": "shared machine: compare ratios measured in the same run, not absolute figures",
        },
    }
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(report, indent=2))
    print(f"reference {ref:.1f} frame-steps/s; written {args.output}")
    for r in results[1:-1]:
        print(f"  {r['variant']:<34} {r['frame_steps_per_s']:7.1f}  x{r['ratio_to_reference']:.2f}")


if __name__ == "__main__":
    main()
