"""Predictor latency by CPU thread count, on a machine with a busy core (issue 35).

A streaming predictor steps one small map at a time: its convolutions are too small to gain
much from a second thread, and a thread that has to share its core with another process makes
every step wait for it. This runs the PyTorch :class:`~lidarflow.predict.Predictor` (bundled
model, the bundled sample's scans, a slow drive's poses as in ``bench_predict.py``) with the
Predictor's default, with 1 and 2 threads set explicitly (``OMP_NUM_THREADS`` and
``threads=``), and with the library's own choice (``threads=None``: one per core, the default
before), first beside a busy process (a Python loop holding one core), then without it.

Each setting is a worker process of its own (so that the environment variable takes effect at
start), holding its Predictor; the workers take turns, a few scans each (``--chunk``), so that
whatever else the machine does falls on every setting alike, and only one runs at a time. The
judged numbers are ratios within one run: the default against the best fixed count, on the
loaded machine. Writes JSON (default ``benchmarks/results/threads.json``).

    python benchmarks/bench_threads.py [--scans 60] [--chunk 5] [--json PATH]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from _output import machine, write_json

HERE = Path(__file__).resolve().parent
#: setting -> Predictor's ``threads`` ("default": not given; None: the library's own choice,
#: one per core, the Predictor's default before issue 35).
SETTINGS: dict[str, int | str | None] = {
    "default": "default",
    "threads=1": 1,
    "threads=2": 2,
    "library": None,
}

# One setting: prints "ready", then for each number K read from stdin steps K more scans
# (the stream wraps around, state reset) and prints their milliseconds as JSON.
_WORKER = """
import json, sys, time
sys.path.insert(0, {here!r})
from bench_predict import drive
from lidarflow.data import read_bag, sample_bag_path
from lidarflow.predict import Predictor
import torch

threads = {threads!r}
predictor = Predictor(None) if threads == "default" else Predictor(None, threads=threads)
scans = list(read_bag(sample_bag_path()))
poses = drive(len(scans))
for scan, pose in zip(scans[:5], poses[:5]):  # warm up
    predictor.update(scan, pose)
i = 5
print(json.dumps({{"ready": True, "torch_threads": torch.get_num_threads()}}), flush=True)
for line in sys.stdin:
    times = []
    for _ in range(int(line)):
        if i == len(scans):
            predictor.reset()
            i = 0
        t0 = time.perf_counter()
        predictor.update(scans[i], poses[i])
        times.append((time.perf_counter() - t0) * 1e3)
        i += 1
    print(json.dumps(times), flush=True)
"""


class Worker:
    """One setting's process."""

    def __init__(self, threads: int | str | None) -> None:
        env = dict(os.environ)
        env.pop("OMP_NUM_THREADS", None)
        if isinstance(threads, int):
            env["OMP_NUM_THREADS"] = str(threads)
        code = _WORKER.format(here=str(HERE), threads=threads)
        self.proc = subprocess.Popen(
            [sys.executable, "-c", code],
            env=env,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        )
        self.torch_threads = self._read()["torch_threads"]

    def _read(self) -> Any:
        assert self.proc.stdout is not None
        line = self.proc.stdout.readline()
        if not line:
            raise SystemExit(f"worker exited with {self.proc.wait()}")
        return json.loads(line)

    def step(self, scans: int) -> list[float]:
        assert self.proc.stdin is not None
        self.proc.stdin.write(f"{scans}\n")
        self.proc.stdin.flush()
        return self._read()

    def close(self) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.close()
        self.proc.wait()


def measure(workers: dict[str, Worker], scans: int, chunk: int) -> dict[str, dict[str, Any]]:
    """``scans`` scans per setting, ``chunk`` at a time, the settings taking turns (the order
    rotated every turn)."""
    names = list(workers)
    times: dict[str, list[float]] = {name: [] for name in names}
    for turn in range(-(-scans // chunk)):
        for name in names[turn % len(names) :] + names[: turn % len(names)]:
            times[name] += workers[name].step(chunk)
    return {
        name: {
            "median_ms": round(float(np.median(ms)), 2),
            "p90_ms": round(float(np.percentile(ms, 90)), 2),
            "scans": len(ms),
            "torch_threads": workers[name].torch_threads,
        }
        for name, ms in times.items()
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scans", type=int, default=60, help="Timed scans per setting.")
    parser.add_argument("--chunk", type=int, default=5, help="Scans per turn.")
    parser.add_argument("--json", type=Path, default=HERE / "results" / "threads.json")
    args = parser.parse_args()
    start = time.perf_counter()
    load_before = os.getloadavg()
    workers = {name: Worker(threads) for name, threads in SETTINGS.items()}
    try:
        loop = subprocess.Popen([sys.executable, "-c", "while True: pass"])
        try:
            time.sleep(0.5)
            busy = measure(workers, args.scans, args.chunk)
        finally:
            loop.kill()
            loop.wait()
        idle = measure(workers, args.scans, args.chunk)
    finally:
        for worker in workers.values():
            worker.close()
    results = {"busy": busy, "idle": idle}
    summary = {}
    for case, rows in results.items():
        best = min(v["median_ms"] for k, v in rows.items() if k.startswith("threads="))
        summary[case] = {
            "default_over_best_fixed": round(rows["default"]["median_ms"] / best, 3),
            "threads2_over_threads1": round(
                rows["threads=2"]["median_ms"] / rows["threads=1"]["median_ms"], 3
            ),
            "library_over_default": round(
                rows["library"]["median_ms"] / rows["default"]["median_ms"], 3
            ),
        }
        shown = ", ".join(f"{k} {v['median_ms']:.1f} ms" for k, v in rows.items())
        print(f"{case}: {shown}; default / best fixed {summary[case]['default_over_best_fixed']}")
    write_json(
        args.json,
        {
            "benchmark": "bench_threads",
            "command": "python benchmarks/bench_threads.py " + " ".join(sys.argv[1:]),
            "machine": machine(),
            "load_average_before": [round(x, 2) for x in load_before],
            "busy_process": "one Python busy loop (one core)",
            "scans_per_setting": args.scans,
            "chunk": args.chunk,
            "results": results,
            "summary": summary,
            "seconds": round(time.perf_counter() - start, 1),
        },
    )


if __name__ == "__main__":
    main()
