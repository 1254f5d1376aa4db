"""How soon a fresh process predicts: seconds from its start (before any import) to the
bundled Predictor's first and second predictions on the sample, with the compiled kernels in
each way they can start (issue 55: the first prediction within 2 s):

- ``first_run``: numba's cache empty, as on a machine's first run; the kernels compile on a
  background thread while their NumPy references serve (the default);
- ``first_run_waiting``: the same, compiling in each kernel's first caller
  (``LIDARFLOW_COMPILED=wait``: how every run began before the background thread);
- ``later_run``: the cache the ``first_run`` left (each round starts from an empty one);
- ``numpy``: no kernels (``LIDARFLOW_COMPILED=0``), the reference the others are divided by.

Also when every kernel asked for was compiled (``compiled_s``), how many were still
compiling at the first prediction, and the slowest update after the first
(``slowest_update_s``: while kernels compile, the compiling thread shares Python's lock).
Each round runs the ways named (``--ways``; all four by default) once, in turn; medians over
``--rounds``. One thread, no poses (scan matching runs). Writes JSON (default
``benchmarks/results/first_prediction.json``).

    python benchmarks/bench_first_prediction.py [--rounds 3] [--scans 100] [--ways ...]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from statistics import median
from typing import Any

from _output import machine, write_json

REPO = Path(__file__).resolve().parent.parent
START = "import time; _t0 = time.perf_counter()\n"
RUN = """
from lidarflow import compiled
from lidarflow.data import read_bag, sample_bag_path
from lidarflow.predict import Predictor
scans = list(read_bag(sample_bag_path()))[:SCANS]
predictor, at, pending = Predictor(threads=1), [], None
for scan in scans:
    predictor.update(scan)
    at.append(time.perf_counter() - _t0)
    pending = compiled._jobs.unfinished_tasks if pending is None else pending
compiled.wait()
steps = [b - a for a, b in zip(at, at[1:])]
print(json.dumps({"first_s": at[0], "second_s": at[1], "last_s": at[-1],
                  "slowest_update_s": max(steps),
                  "compiled_s": time.perf_counter() - _t0, "pending_at_first": pending,
                  "failed": compiled.failed}))
"""
WAYS = {  # LIDARFLOW_COMPILED, cache: fresh (emptied first) or kept
    "first_run": ("1", "fresh"),
    "first_run_waiting": ("wait", "fresh"),
    "later_run": ("1", "kept"),
    "numpy": ("0", "fresh"),
}


def run_once(mode: str, cache: Path, scans: int) -> dict[str, Any]:
    """One process: its times, as the script prints them."""
    env = {**os.environ, "LIDARFLOW_COMPILED": mode, "NUMBA_CACHE_DIR": str(cache)}
    env.update(OMP_NUM_THREADS="1", PYTHONPATH=str(REPO / "src"))
    script = START + "import json\n" + RUN.replace("SCANS", str(scans))
    done = subprocess.run(
        [sys.executable, "-c", script], env=env, capture_output=True, text=True, check=True
    )
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--scans", type=int, default=100)
    parser.add_argument(
        "--ways", nargs="+", choices=list(WAYS), default=list(WAYS),
        help="the ways timed (later_run reads the cache first_run leaves: it needs first_run)",
    )  # fmt: skip
    parser.add_argument(
        "--json", type=Path, default=REPO / "benchmarks" / "results" / "first_prediction.json"
    )
    args = parser.parse_args()
    if "later_run" in args.ways and "first_run" not in args.ways:
        parser.error("later_run reads the cache first_run leaves: name first_run too")
    if "numpy" not in args.ways:
        parser.error("numpy is the reference the others are divided by: name it too")
    ways = {way: WAYS[way] for way in WAYS if way in args.ways}
    runs: dict[str, list[dict[str, Any]]] = {way: [] for way in ways}
    load = [os.getloadavg()[0]]
    for r in range(args.rounds):
        with tempfile.TemporaryDirectory() as folder:
            for way, (mode, cache) in ways.items():
                # a fresh cache: a folder of its own; the later run reads the first run's
                where = Path(folder) / ("first_run" if cache == "kept" else way)
                runs[way].append(run_once(mode, where, args.scans))
                print(f"round {r + 1}, {way}: {runs[way][-1]}", flush=True)
    load.append(os.getloadavg()[0])
    numpy_first = median(x["first_s"] for x in runs["numpy"])
    result: dict[str, Any] = {"machine": machine(), "load_before_after": load, "ways": {}}
    for way, got in runs.items():
        keys = ("first_s", "second_s", "compiled_s", "slowest_update_s")
        row = {k: median(x[k] for x in got) for k in keys}
        row["first_vs_numpy"] = row["first_s"] / numpy_first
        row["pending_at_first"] = [x["pending_at_first"] for x in got]
        row["failed"] = sorted({name for x in got for name in x["failed"]})
        result["ways"][way] = row
    result["rounds"], result["scans"] = args.rounds, args.scans
    write_json(args.json, result)
    print(json.dumps(result["ways"], indent=1))


if __name__ == "__main__":
    main()
