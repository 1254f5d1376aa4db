"""Predictor latency by CPU thread count, on a machine with a busy core (issue 35).

A streaming predictor steps one small map at a time: its convolutions are too small to gain
much from a second thread, and a thread that has to share its core with another process makes
every step wait for it. This runs the PyTorch :class:`~lidarflow.predict.Predictor` (bundled
model, the bundled sample's scans, a slow drive's poses as in ``bench_predict.py``) beside a
busy process (a Python loop holding one core), once with the Predictor's default, and with 1
and 2 threads set explicitly (``OMP_NUM_THREADS`` and ``threads=``); each setting runs in a
fresh process, so that the environment variable takes effect. The same without the busy
process gives the idle machine's figures. The judged numbers are ratios within one run: the
default against the best fixed count, on the loaded machine. Writes JSON (default
``benchmarks/results/threads.json``).

    python benchmarks/bench_threads.py [--scans 30] [--json PATH]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

from _output import machine, write_json

HERE = Path(__file__).resolve().parent
SETTINGS = {"default": None, "threads=1": 1, "threads=2": 2}

# One setting, in its own process: prints {"median_ms", "p90_ms", "torch_threads"}.
_WORKER = """
import json, sys, time
import numpy as np
sys.path.insert(0, {here!r})
from bench_predict import drive
from lidarflow.data import read_bag, sample_bag_path
from lidarflow.predict import Predictor
import torch

threads, n = {threads!r}, {scans!r}
predictor = Predictor(None) if threads is None else Predictor(None, threads=threads)
scans = list(read_bag(sample_bag_path()))[: n + 5]
poses = drive(len(scans))
times = []
for i, (scan, pose) in enumerate(zip(scans, poses)):
    t0 = time.perf_counter()
    predictor.update(scan, pose)
    if i >= 5:  # the first steps warm the allocator up
        times.append(time.perf_counter() - t0)
ms = np.array(times) * 1e3
print(json.dumps({{"median_ms": float(np.median(ms)), "p90_ms": float(np.percentile(ms, 90)),
                  "torch_threads": torch.get_num_threads()}}))
"""


def run_setting(threads: int | None, scans: int) -> dict[str, float]:
    env = dict(os.environ)
    env.pop("OMP_NUM_THREADS", None)
    if threads is not None:
        env["OMP_NUM_THREADS"] = str(threads)
    code = _WORKER.format(here=str(HERE), threads=threads, scans=scans)
    done = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=False
    )
    if done.returncode != 0:
        raise SystemExit(f"worker failed: {done.stderr[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def measure(scans: int, busy: bool) -> dict[str, dict[str, float]]:
    loop = None
    if busy:
        loop = subprocess.Popen([sys.executable, "-c", "while True: pass"])
        time.sleep(0.5)
    try:
        return {name: run_setting(threads, scans) for name, threads in SETTINGS.items()}
    finally:
        if loop is not None:
            loop.kill()
            loop.wait()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scans", type=int, default=30, help="Timed scans per setting.")
    parser.add_argument("--json", type=Path, default=HERE / "results" / "threads.json")
    args = parser.parse_args()
    start = time.perf_counter()
    load_before = os.getloadavg()
    results = {"busy": measure(args.scans, busy=True), "idle": measure(args.scans, busy=False)}
    summary = {}
    for case, rows in results.items():
        best = min(v["median_ms"] for k, v in rows.items() if k != "default")
        summary[case] = {
            "default_over_best_fixed": round(rows["default"]["median_ms"] / best, 3),
            "threads2_over_threads1": round(
                rows["threads=2"]["median_ms"] / rows["threads=1"]["median_ms"], 3
            ),
        }
    for case, rows in results.items():
        shown = ", ".join(f"{k} {v['median_ms']:.1f} ms" for k, v in rows.items())
        print(f"{case}: {shown}; default / best fixed {summary[case]['default_over_best_fixed']}")
    write_json(
        args.json,
        {
            "benchmark": "bench_threads",
            "command": "python benchmarks/bench_threads.py " + " ".join(sys.argv[1:]),
            "machine": machine(),
            "load_average_before": [round(x, 2) for x in load_before],
            "scans_per_setting": args.scans,
            "busy_process": "one Python busy loop (one core)",
            "results": results,
            "summary": summary,
            "seconds": round(time.perf_counter() - start, 1),
        },
    )


if __name__ == "__main__":
    main()
