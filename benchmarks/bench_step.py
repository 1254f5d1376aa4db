"""The Predictor's step, roll-out, online decision and scan matching against a reference commit,
measured in the same run, with a fixed reference workload beside them so that the numbers travel
between machines (issues 46 and 55).

Three variants, each a worker process of its own per thread count (``PYTHONPATH`` at its tree's
``src``, ``OMP_NUM_THREADS`` and ``threads=`` set, launched from a temporary folder):

- ``reference``: the reference commit's ``src`` (default ``d4a70f5``, issue 55's baseline),
  taken out with ``git archive`` into a temporary folder;
- ``current_numpy``: this checkout (or ``--current``) with ``LIDARFLOW_COMPILED=0``, the NumPy
  references of the compiled kernels (:mod:`lidarflow.compiled`); the default backend only,
  unless ``--numpy-onnx``;
- ``current``: the same tree with the compiled kernels where numba is installed
  (``compiled_kernels`` in the JSON says whether they ran).

Each worker holds one Predictor per setting on the bundled sample's scans. Settings, each with
the bundled model's default backend (the NumPy head step where the tree has it) and with its
ONNX export (``--backends``):

- ``fixed``: update with a slow drive's poses (as ``bench_predict.py`` gives them, odometry
  check off), the decision at its fixed offset;
- ``online``: the same with the online decision (its cost: the ratio to ``fixed``);
- ``online_h8``: with ``horizon=8`` (one roll-out step: ``(online_h8 - online) / 7``);
- ``noposes``: ``update(scan)`` without poses (the motion matched from the scans), the online
  decision, horizon 1, the Predictor's default options otherwise.

The reference workload is a NumPy FFT (``np.fft.fft2``, three times) of a fixed 240 x 240
complex array, about 1.4 ms on one core, timed in every worker as one more item of each round. The
workers take turns, a chunk of scans (or of workloads) each, the order reversed every other
round, so whatever else the machine does falls on all alike. Every ``..._ms`` figure is also
given per reference workload (``..._per_reference``: the figure over the workload's median
pooled over all workers): a machine twice as fast should give about the same
``_per_reference``. Derived: ``rollout_step_ms`` and ``one_second_at_40hz_ms`` (an estimate:
``online`` plus 40 roll-out steps, as a horizon of one second at 40 Hz would take).

Batched (``--batch``; ``--batch`` without values or ``--no-batch`` skips it): scans/s for ``B``
streams, the model's PyTorch step on a batch of ``B`` (every tree) and, where the tree has it,
``B`` streams of the NumPy head step one after another, each ``B`` over at least
``--batch-scans`` scans. Writes JSON (default
``benchmarks/results/step.json``) with the medians, the ratios of both current variants to the
reference, and the load (``uptime``) before and after.

    python benchmarks/bench_step.py [--scans 60] [--chunk 10] [--threads 1 2] [--batch 1 8 64]
    python benchmarks/bench_step.py --scans 6 --chunk 3 --threads 1 --no-batch  # a quick look
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
REFERENCE = "d4a70f5"  # issue 55's baseline (issue 46 measured against d4a7e7a)
SETTINGS = ("fixed", "online", "online_h8", "noposes")
BACKENDS = ("default", "onnx")
ROLLOUT = 8
#: One second of roll-out at 40 Hz (the derived ``one_second_at_40hz_ms``).
STEPS_A_SECOND = 40
#: The reference workload: ``np.fft.fft2`` of a fixed ``FFT_SIZE`` square complex array
#: (``default_rng(0)``'s normals) into one buffer, ``FFT_REPEAT`` times a sample (about 1.4 ms on
#: one core of a 2-core cloud VM); warmed up at the worker's start and once untimed before every
#: chunk (after a chunk of scans the cache holds theirs). 240, not 256: a power of two's strides
#: made it 1.84 to 2.08 ms from one process to another, 240's 1.36 to 1.40 ms.
FFT_SIZE, FFT_REPEAT = 240, 3
WORKLOAD = "workload"

# One worker: prints its description (a JSON line), then answers each request line with one
# JSON line: "run BACKEND SETTING K" steps K more scans of that Predictor and returns their
# milliseconds; "workload K" times the reference workload K times; "batched B STEPS" returns
# scans/s of B streams stepped together. Written for the reference tree's API too (no
# lidarflow.predict.step there: HeadStepBackend.run(maps, state, motion)).
_WORKER = r"""
import json, sys, time
import numpy as np
import torch
import lidarflow
from lidarflow.data import read_bag, sample_bag_path
from lidarflow.models.presets import bundled_model_dir, resolve_model
from lidarflow.predict import Predictor

threads, rollout = int(sys.argv[1]), int(sys.argv[2])
backends = sys.argv[3].split(",")
fft_size, fft_repeat = int(sys.argv[4]), int(sys.argv[5])
torch.set_num_threads(threads)
scans = list(read_bag(sample_bag_path()))
n = len(scans)
i = np.arange(4 * n, dtype=np.float64)
yaw = np.deg2rad(0.5) * i  # a slow drive: 5 cm forward and 0.5 degrees left a scan
poses = np.stack([0.05 * np.cumsum(np.cos(yaw)), 0.05 * np.cumsum(np.sin(yaw)), yaw], axis=1)
models = {"default": None, "onnx": str(bundled_model_dir() / "model.onnx")}
settings = {  # online decision, horizon, poses given
    "fixed": (False, 1, True),
    "online": (True, 1, True),
    "online_h8": (True, rollout, True),
    "noposes": (True, 1, False),
}
predictors, at = {}, {}
for b in backends:
    for s, (online, horizon, given) in settings.items():
        options = {"threads": threads, "online_decision": online, "horizon": horizon}
        if given:
            options["check_odometry"] = False
        p = Predictor(models[b], **options)
        for k in range(10):  # warm up (and compile, where numba compiles)
            p.update(scans[k], poses[k]) if given else p.update(scans[k])
        predictors[b, s], at[b, s] = p, 10
try:
    from lidarflow import compiled
    compiled_kernels = compiled.available()
    if hasattr(compiled, "wait"):  # kernels compiled in the background: all of them, first
        compiled.wait()
except ImportError:  # a tree without compiled kernels
    compiled_kernels = None
# Complex in, written into one buffer: no new array a call, whose pages (over malloc's mmap
# threshold, which moves with the process's history) would make it bimodal (1.4 or 3.5 ms).
workload = np.random.default_rng(0).standard_normal((fft_size, fft_size)).astype(np.complex128)
try:
    fft_out = {"out": np.empty_like(workload)}
    np.fft.fft2(workload, **fft_out)
except TypeError:  # NumPy before 2.0: no out=
    fft_out = {}
for _ in range(20):  # warm up
    np.fft.fft2(workload, **fft_out)
print(json.dumps({
    "backends": {b: type(predictors[b, "fixed"].backend).__name__ for b in backends},
    "compiled_kernels": compiled_kernels,
    "lidarflow": lidarflow.__file__,
}), flush=True)

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
    try:
        from lidarflow.predict.step import StepInputs
    except ImportError:  # before the step contract: run(maps, state, motion)
        StepInputs = None
    backends = [HeadStepBackend(net) for _ in range(batch)]
    states = [b.init_state(100, 100) for b in backends]
    maps = x.numpy()[:, None]
    m = motion[0].numpy()
    t0 = time.perf_counter()
    for _ in range(steps):
        for j, b in enumerate(backends):
            if StepInputs is None:
                states[j] = b.run(maps[j], states[j], m)[2]
            else:
                states[j] = b.run(StepInputs(maps[j], m), states[j])[2]
    out["numpy_streams"] = batch * steps / (time.perf_counter() - t0)
    return out

def timed_workload(k):
    np.fft.fft2(workload, **fft_out)  # untimed: the cache is the scans' after a chunk of them
    times = []
    for _ in range(k):
        t0 = time.perf_counter()
        for _ in range(fft_repeat):
            np.fft.fft2(workload, **fft_out)
        times.append((time.perf_counter() - t0) * 1e3)
    return times

for line in sys.stdin:
    words = line.split()
    if words[0] == "batched":
        print(json.dumps(batched(int(words[1]), int(words[2]))), flush=True)
        continue
    if words[0] == "workload":
        print(json.dumps(timed_workload(int(words[1]))), flush=True)
        continue
    key, k = (words[1], words[2]), int(words[3])
    given = settings[words[2]][2]
    p, j = predictors[key], at[key]
    times = []
    for _ in range(k):
        t0 = time.perf_counter()
        if given:
            p.update(scans[j % n], poses[j])
        else:
            p.update(scans[j % n])
        times.append((time.perf_counter() - t0) * 1e3)
        j += 1
        # The stream starts again: with poses after the drive, without after the recording
        # (its last scan is not matched against its first).
        if j >= (len(poses) if given else n):
            p.reset()
            j = 0
    at[key] = j
    print(json.dumps(times), flush=True)
"""


class Worker:
    """One variant at one thread count: a worker process answering requests line by line."""

    def __init__(self, tree: Path, threads: int, backends: list[str], env: dict[str, str]) -> None:
        self.backends = backends
        full_env = {
            **os.environ,
            **env,
            "PYTHONPATH": str(tree / "src"),
            "OMP_NUM_THREADS": str(threads),
            "MKL_NUM_THREADS": str(threads),
            "OPENBLAS_NUM_THREADS": str(threads),
        }
        self.proc = subprocess.Popen(
            [
                sys.executable, "-c", _WORKER, str(threads), str(ROLLOUT), ",".join(backends),
                str(FFT_SIZE), str(FFT_REPEAT),
            ],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            env=full_env,
            cwd=tempfile.gettempdir(),  # no checkout's src on the path but the tree's
        )  # fmt: skip
        self.info = self._read()
        expected = (tree / "src").resolve()
        if not Path(self.info["lidarflow"]).resolve().is_relative_to(expected):
            raise RuntimeError(f"a worker imported {self.info['lidarflow']}, not {expected}")

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


def describe(tree: Path) -> str:
    """``git describe --always --dirty`` of ``tree`` ("" outside a git checkout)."""
    done = subprocess.run(
        ["git", "-C", str(tree), "describe", "--always", "--dirty"],
        capture_output=True,
        text=True,
        check=False,
    )
    return done.stdout.strip() if done.returncode == 0 else ""


def summary(times: dict[str, list[float]], backends: list[str]) -> dict[str, Any]:
    """Medians (ms) of one worker's timings and the figures derived from them."""
    med = {k: float(np.median(v)) for k, v in times.items() if k != WORKLOAD}
    out: dict[str, Any] = {f"{k}_median_ms": v for k, v in med.items()}
    for b in backends:
        online = med[f"{b}/online"]
        step = (med[f"{b}/online_h8"] - online) / (ROLLOUT - 1)
        out[f"{b}_online_decision_added"] = online / med[f"{b}/fixed"] - 1.0
        out[f"{b}_rollout_step_ms"] = step
        out[f"{b}_one_second_at_40hz_ms"] = online + STEPS_A_SECOND * step
    return out


def per_reference(row: dict[str, Any], workload_ms: float) -> dict[str, float]:
    """Every ``..._ms`` figure of ``row`` over the reference workload's median."""
    return {f"{k[:-3]}_per_reference": v / workload_ms for k, v in row.items() if k.endswith("_ms")}


def ratios(cur: dict[str, Any], ref: dict[str, Any]) -> dict[str, float]:
    """``cur / ref`` for every ``..._ms`` figure both have."""
    return {k: cur[k] / ref[k] for k in cur if k.endswith("_ms") and ref.get(k)}


DERIVED = {
    "online_decision_added": "online / fixed - 1: what the online decision adds to an update",
    "rollout_step_ms": "(online_h8 - online) / 7: one more roll-out step",
    "one_second_at_40hz_ms": (
        "an estimate, not measured: online + 40 * rollout_step_ms, an update rolled out one "
        "second ahead at 40 Hz (horizon 40) if every roll-out step costs what horizon 8's do"
    ),
    "per_reference": (
        "a figure in ms over the reference workload's median (pooled over every worker of the "
        "run): comparable between machines"
    ),
    "fixed_vs_threads": "fixed at this thread count over fixed at the first thread count",
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reference", default=REFERENCE, help="the commit compared against")
    parser.add_argument(
        "--current", type=Path, default=REPO, help="the tree measured (its src), this checkout"
    )
    parser.add_argument("--scans", type=int, default=60, help="scans per setting and worker")
    parser.add_argument("--chunk", type=int, default=10)
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--backends", nargs="+", choices=BACKENDS, default=list(BACKENDS))
    parser.add_argument(
        "--numpy-onnx",
        action="store_true",
        help="run current_numpy with the ONNX backend too (by default the default backend only)",
    )
    parser.add_argument(
        "--batch", type=int, nargs="*", default=[1, 8, 64], help="no values: skip batched"
    )
    parser.add_argument("--no-batch", dest="batch", action="store_const", const=[])
    parser.add_argument(
        "--batch-steps", type=int, default=5, help="steps per batch size, at the least"
    )
    parser.add_argument(
        "--batch-scans",
        type=int,
        default=320,
        help="scans each batch size is timed over, at the least (B = 1 over 5 steps was noise)",
    )
    parser.add_argument("--json", type=Path, default=Path("benchmarks/results/step.json"))
    args = parser.parse_args()
    current = args.current.resolve()
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
        numpy_backends = [b for b in args.backends if args.numpy_onnx or b == "default"]
        variants: dict[str, tuple[Path, dict[str, str], list[str]]] = {
            "reference": (ref_tree, {}, list(args.backends)),
            "current_numpy": (current, {"LIDARFLOW_COMPILED": "0"}, numpy_backends),
            "current": (current, {"LIDARFLOW_COMPILED": "1"}, list(args.backends)),
        }
        variants = {v: spec for v, spec in variants.items() if spec[2]}
        workers = {
            (v, n): Worker(tree, n, backends, env)
            for v, (tree, env, backends) in variants.items()
            for n in args.threads
        }
        times: dict[tuple[str, int], dict[str, list[float]]] = {w: {} for w in workers}
        rounds = max(1, args.scans // args.chunk)
        order = list(workers)
        items = [f"run {b} {s}" for b in args.backends for s in SETTINGS] + [WORKLOAD]
        for r in range(rounds):
            for item in items:
                # Alternate who goes first, so no variant always follows another.
                for w in order if r % 2 == 0 else order[::-1]:
                    if item == WORKLOAD:
                        key = WORKLOAD
                    else:
                        _, b, s = item.split()
                        if b not in workers[w].backends:
                            continue
                        key = f"{b}/{s}"
                    got = workers[w].ask(f"{item} {args.chunk}")
                    times[w].setdefault(key, []).extend(got)
        batched: dict[str, Any] = {}
        for n in args.threads:
            for bsize in args.batch:
                for v in variants:
                    steps = max(args.batch_steps, -(-args.batch_scans // bsize))
                    got = workers[v, n].ask(f"batched {bsize} {steps}")
                    batched[f"{v}/threads={n}/B={bsize}"] = got
        pooled = [t for w in workers for t in times[w][WORKLOAD]]
        workload_ms = float(np.median(pooled))
        for (v, n), w in workers.items():
            row = {
                "default_backend": w.info["backends"].get("default"),
                "backends": w.info["backends"],
                "compiled_kernels": w.info["compiled_kernels"],
                "reference_workload_median_ms": float(np.median(times[v, n][WORKLOAD])),
                **summary(times[v, n], w.backends),
            }
            results.setdefault(f"threads={n}", {})[v] = row
            w.close()
    for n in args.threads:
        row = results[f"threads={n}"]
        for v in variants:
            row[v].update(per_reference(row[v], workload_ms))
        ref = row["reference"]
        for v in ("current_numpy", "current"):
            if v in row:
                row[f"ratio_{v}_to_reference"] = ratios(row[v], ref)
        if "current_numpy" in row:
            row["ratio_current_to_current_numpy"] = ratios(row["current"], row["current_numpy"])
        print(f"threads={n}: {' -> '.join(variants)} (ms; ratios to the reference)")
        for k in (k for k in ref if k.endswith("_ms")):
            figures = " -> ".join(f"{row[v][k]:.3f}" if k in row[v] else "-" for v in variants)
            ratio = ", ".join(
                f"{row[f'ratio_{v}_to_reference'][k]:.2f}x"
                for v in variants
                if k in row[v] and v != "reference"
            )
            print(f"  {k}: {figures} ({ratio})")
        for b in args.backends:
            key = f"{b}_online_decision_added"
            added = " -> ".join(f"{row[v][key]:+.0%}" if key in row[v] else "-" for v in variants)
            print(f"  {key}: {added}")
    first = args.threads[0]
    for n in args.threads[1:]:
        for v in variants:
            one = results[f"threads={first}"][v]["default/fixed_median_ms"]
            more = results[f"threads={n}"][v]["default/fixed_median_ms"]
            results[f"threads={n}"][v][f"fixed_vs_threads={first}"] = more / one
    for k, got in batched.items():
        print(f"batched {k}: " + ", ".join(f"{a} {r:,.0f} scans/s" for a, r in got.items()))
    print(f"reference workload: {workload_ms:.3f} ms (median of {len(pooled)})")
    out = {
        "benchmark": "step",
        "reference": args.reference,
        "current": describe(current),
        "variants": {
            v: {
                "tree": f"{args.reference} (git archive)" if v == "reference" else str(current),
                "env": env,
                "backends": backends,
            }
            for v, (_, env, backends) in variants.items()
        },
        "scans_per_setting": rounds * args.chunk,
        "batch_scans": args.batch_scans,
        "rollout_horizon": ROLLOUT,
        "machine": machine(),
        "load_before": load_before,
        "load_after": uptime(),
        "reference_workload": {
            "description": (
                f"np.fft.fft2 of a fixed {FFT_SIZE} x {FFT_SIZE} complex128 array "
                f"(default_rng(0) normals) into one buffer, {FFT_REPEAT} times a sample, one "
                "thread, in every worker between the scans' chunks"
            ),
            "numpy": np.__version__,
            "median_ms": workload_ms,
            "samples": len(pooled),
        },
        "derived": DERIVED,
        "results": results,
        "batched_scans_per_s": batched,
    }
    write_json(args.json, out)


if __name__ == "__main__":
    main()
