"""The Predictor's step, roll-out and online decision against a reference commit, measured in
the same run (issue 46).

The reference's ``src`` (default ``d4a7e7a``, where issue 46 measured) is taken out with
``git archive`` into a temporary folder; each of (reference, this checkout) x thread count is a
worker process of its own (``PYTHONPATH`` at its tree, ``OMP_NUM_THREADS`` and ``threads=``
set), holding one Predictor per setting on the bundled sample's scans, given a slow drive's
poses as ``bench_predict.py`` does (odometry check off). The workers take turns, a chunk of
scans each, so whatever else the machine does falls on both alike. Settings, each with the
bundled model's default backend (PyTorch where installed) and with its ONNX export:

- ``fixed``: update with poses, the decision at its fixed offset;
- ``online``: the same with the online decision (its cost: the ratio to ``fixed``);
- ``online_h8``: with ``horizon=8`` (one roll-out step: ``(online_h8 - online) / 7``).

Batched: scans/s for ``B`` streams (``--batch``), the model's PyTorch step on a batch of ``B``
(both trees) and, where the checkout has it, ``B`` streams of the NumPy head step one after
another. Writes JSON (default ``benchmarks/results/step.json``) with the medians, the ratios
this checkout / reference, and the load (``uptime``) before and after.

    python benchmarks/bench_step.py [--scans 60] [--chunk 10] [--threads 1 2] [--batch 1 8 64]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
from _output import machine, write_json

REPO = Path(__file__).resolve().parent.parent
SETTINGS = ("fixed", "online", "online_h8")
BACKENDS = ("default", "onnx")
ROLLOUT = 8

# One worker: prints "ready", then answers each request line with one JSON line:
# "run BACKEND SETTING K" steps K more scans of that Predictor and returns their milliseconds;
# "batched B STEPS" returns scans/s of B streams stepped together.
_WORKER = r"""
import json, sys, time
import numpy as np
import torch
from lidarflow.data import read_bag, sample_bag_path
from lidarflow.models.presets import bundled_model_dir, resolve_model
from lidarflow.predict import Predictor
from lidarflow.predict.step import StepInputs

threads, rollout = int(sys.argv[1]), int(sys.argv[2])
torch.set_num_threads(threads)
scans = list(read_bag(sample_bag_path()))
n = len(scans)
i = np.arange(4 * n, dtype=np.float64)
yaw = np.deg2rad(0.5) * i  # a slow drive: 5 cm forward and 0.5 degrees left a scan
poses = np.stack([0.05 * np.cumsum(np.cos(yaw)), 0.05 * np.cumsum(np.sin(yaw)), yaw], axis=1)
models = {"default": None, "onnx": str(bundled_model_dir() / "model.onnx")}
settings = {"fixed": (False, 1), "online": (True, 1), "online_h8": (True, rollout)}
predictors, at = {}, {}
for b, model in models.items():
    for s, (online, horizon) in settings.items():
        p = Predictor(model, threads=threads, check_odometry=False, online_decision=online,
                      horizon=horizon)
        for k in range(10):  # warm up
            p.update(scans[k], poses[k])
        predictors[b, s], at[b, s] = p, 10
print(json.dumps({"backend": type(predictors["default", "fixed"].backend).__name__}), flush=True)

def batched(batch, steps):
    net, _ = resolve_model(None)
    net = net.eval()
    x = (torch.rand(batch, net.input_channels, 100, 100) > 0.9).float()
    state = net.init_state(batch, 100, 100)
    motion = torch.tensor([[0.5, 0.0, 0.0087]]).expand(batch, 3)
    out = {}
    with torch.inference_mode():
        for _ in range(2):
            o, state = net.step(x, state, motion)
        t0 = time.perf_counter()
        for _ in range(steps):
            o, state = net.step(x, state, motion)
            net.predict_next(x, o)
        out["torch_batched"] = batch * steps / (time.perf_counter() - t0)
    try:
        from lidarflow.predict.headstep import HeadStepBackend
    except ImportError:
        return out
    backends = [HeadStepBackend(net) for _ in range(batch)]
    states = [b.init_state(100, 100) for b in backends]
    maps = x.numpy()[:, None]
    m = motion[0].numpy()
    t0 = time.perf_counter()
    for _ in range(steps):
        for j, b in enumerate(backends):
            _, _, states[j] = b.run(StepInputs(maps[j], m), states[j])
    out["numpy_streams"] = batch * steps / (time.perf_counter() - t0)
    return out

for line in sys.stdin:
    words = line.split()
    if words[0] == "batched":
        print(json.dumps(batched(int(words[1]), int(words[2]))), flush=True)
        continue
    key, k = (words[1], words[2]), int(words[3])
    p, j = predictors[key], at[key]
    times = []
    for _ in range(k):
        t0 = time.perf_counter()
        p.update(scans[j % n], poses[j])
        times.append((time.perf_counter() - t0) * 1e3)
        j += 1
        if j >= len(poses):  # the stream starts again
            p.reset()
            j = 0
    at[key] = j
    print(json.dumps(times), flush=True)
"""


class Worker:
    def __init__(self, tree: Path, threads: int) -> None:
        env = {
            **os.environ,
            "PYTHONPATH": str(tree / "src"),
            "OMP_NUM_THREADS": str(threads),
        }
        self.proc = subprocess.Popen(
            [sys.executable, "-c", _WORKER, str(threads), str(ROLLOUT)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            env=env,
            cwd=tempfile.gettempdir(),  # no checkout's src on the path but the tree's
        )
        self.info = self._read()

    def _read(self) -> Any:
        assert self.proc.stdout is not None
        line = self.proc.stdout.readline()
        if not line:
            raise RuntimeError("a worker died (see its stderr above)")
        return json.loads(line)

    def ask(self, request: str) -> Any:
        assert self.proc.stdin is not None
        self.proc.stdin.write(request + "\n")
        self.proc.stdin.flush()
        return self._read()

    def close(self) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.close()
        self.proc.wait()


def uptime() -> str:
    return subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()


def summary(times: dict[str, list[float]]) -> dict[str, Any]:
    med = {k: float(np.median(v)) for k, v in times.items()}
    out: dict[str, Any] = {f"{k}_median_ms": v for k, v in med.items()}
    for b in BACKENDS:
        out[f"{b}_online_decision_added"] = med[f"{b}/online"] / med[f"{b}/fixed"] - 1.0
        out[f"{b}_rollout_step_ms"] = (med[f"{b}/online_h8"] - med[f"{b}/online"]) / (ROLLOUT - 1)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reference", default="d4a7e7a")
    parser.add_argument("--scans", type=int, default=60, help="scans per setting and worker")
    parser.add_argument("--chunk", type=int, default=10)
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--batch", type=int, nargs="+", default=[1, 8, 64])
    parser.add_argument("--batch-steps", type=int, default=5)
    parser.add_argument("--json", type=Path, default=Path("benchmarks/results/step.json"))
    args = parser.parse_args()
    load_before = uptime()
    results: dict[str, Any] = {}
    with tempfile.TemporaryDirectory() as tmp:
        ref_tree = Path(tmp)
        archive = subprocess.run(
            ["git", "-C", str(REPO), "archive", args.reference, "src"],
            check=True,
            capture_output=True,
        ).stdout
        subprocess.run(["tar", "-x", "-C", str(ref_tree)], input=archive, check=True)
        trees = {"reference": ref_tree, "current": REPO}
        workers = {(t, n): Worker(tree, n) for t, tree in trees.items() for n in args.threads}
        times: dict[tuple[str, int], dict[str, list[float]]] = {w: {} for w in workers}
        rounds = max(1, args.scans // args.chunk)
        order = list(workers)
        for r in range(rounds):
            for b in BACKENDS:
                for s in SETTINGS:
                    # Alternate who goes first, so neither tree always follows the other.
                    for w in order if r % 2 == 0 else order[::-1]:
                        got = workers[w].ask(f"run {b} {s} {args.chunk}")
                        times[w].setdefault(f"{b}/{s}", []).extend(got)
        batched: dict[str, Any] = {}
        for n in args.threads:
            for bsize in args.batch:
                for t in trees:
                    got = workers[t, n].ask(f"batched {bsize} {args.batch_steps}")
                    batched[f"{t}/threads={n}/B={bsize}"] = got
        for (t, n), w in workers.items():
            results.setdefault(f"threads={n}", {})[t] = {
                "default_backend": w.info["backend"],
                **summary(times[t, n]),
            }
            w.close()
    for n in args.threads:
        row = results[f"threads={n}"]
        ref, cur = row["reference"], row["current"]
        row["ratio_current_to_reference"] = {
            k: cur[k] / ref[k] for k in cur if k.endswith("_ms") and ref.get(k)
        }
        print(f"threads={n}")
        for k, v in row["ratio_current_to_reference"].items():
            print(f"  {k}: {ref[k]:.3f} -> {cur[k]:.3f} ms ({v:.2f}x)")
        for b in BACKENDS:
            key = f"{b}_online_decision_added"
            print(f"  {key}: {ref[key]:+.0%} -> {cur[key]:+.0%}")
    for n in args.threads[1:]:
        for t in ("reference", "current"):
            one = results[f"threads={args.threads[0]}"][t]["default/fixed_median_ms"]
            more = results[f"threads={n}"][t]["default/fixed_median_ms"]
            results[f"threads={n}"][t][f"fixed_vs_threads={args.threads[0]}"] = more / one
    for k, v in batched.items():
        print(f"batched {k}: " + ", ".join(f"{a} {r:,.0f} scans/s" for a, r in v.items()))
    out = {
        "benchmark": "step",
        "reference": args.reference,
        "scans_per_setting": rounds * args.chunk,
        "rollout_horizon": ROLLOUT,
        "machine": machine(),
        "load_before": load_before,
        "load_after": uptime(),
        "results": results,
        "batched_scans_per_s": batched,
    }
    write_json(args.json, out)


if __name__ == "__main__":
    main()
