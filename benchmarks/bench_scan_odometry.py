"""Per-scan cost of finding the sensor's motion from the scans (robots without odometry), as
ratios to the code at ``d4a7e7a`` (issue 46's reference) measured in the same run.

For each recording, two timings per frame, one thread: scan matching alone
(:class:`lidarflow.motion.scanmatch.ScanOdometry` fed the maps and the returns, what a
Predictor without poses does) and ``Predictor.update`` of the bundled model without poses.
The reference is ``git archive``'d into a temporary folder and both codes run in
subprocesses (``PYTHONPATH`` pointing at each), alternating, ``--rounds`` times each; a
timing is the median over frames, then over rounds, taken as wall time and as the thread's CPU
time (on a loaded shared CPU the wall time also counts the waits for a core). Beside the speed:
the motions found, and where the recording has odometry their median error against it (as
``studies/scan_odometry.py`` measures), for both codes. Writes JSON (default
``benchmarks/results/scan_odometry.json``).

    python benchmarks/bench_scan_odometry.py [--frames 150] [--rounds 2] [RECORDING ...]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from _output import machine, write_json

REFERENCE = "d4a7e7a"
ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data"
TIMINGS = ("scan_matching", "scan_matching_cpu", "update_without_poses", "update_without_poses_cpu")
RECORDINGS = [
    SHARED / "positive_2.bag",  # standing still, 768 beams 7.5 Hz: issue 46's recording
    SHARED / "general_tracking_moving_1.bag.zip",  # driving, with odometry
    SHARED / "datmo_overtakes.bag",  # a car, 360 beams
]


def worker(recording: str, frames: int) -> dict[str, Any]:
    """Timings and motions of whichever lidarflow is on the path (run in a subprocess)."""
    import torch

    import lidarflow
    from lidarflow.data import load_any
    from lidarflow.motion.icp import recording_points
    from lidarflow.motion.scanmatch import ScanOdometry
    from lidarflow.predict import Predictor
    from lidarflow.scan import GridSpec

    expected = Path(os.environ["PYTHONPATH"].split(":")[0]).resolve()
    if not Path(lidarflow.__file__).resolve().is_relative_to(expected):
        raise SystemExit(f"imported {lidarflow.__file__}, not the code under {expected}")
    torch.set_num_threads(1)
    rec = load_any(Path(recording))
    rec = rec.slice(0, min(frames, len(rec)))
    grid = GridSpec()
    occupancy, points = rec.maps(grid)[0], recording_points(rec)
    odometry, motions, matching = ScanOdometry(grid.res), [], []
    for t in range(len(rec)):
        start = _clocks()
        found = odometry.update(occupancy[t], points[t])
        matching.append(_clocks() - start)
        motions.append([np.nan] * 3 if found is None else [float(v) for v in found])
    predictor, update = Predictor(threads=1), []
    for scan in rec:
        start = _clocks()
        predictor.update(scan)
        update.append(_clocks() - start)
    # (wall, CPU) medians of each, frame 0 left out (nothing to match it with)
    matched, updated = (1e3 * np.median(np.asarray(t)[1:], axis=0) for t in (matching, update))
    return {
        "scan_matching_ms": float(matched[0]),
        "scan_matching_cpu_ms": float(matched[1]),
        "update_without_poses_ms": float(updated[0]),
        "update_without_poses_cpu_ms": float(updated[1]),
        "motions": motions,
        "poses": None if rec.poses is None else np.asarray(rec.poses).tolist(),
    }


def _clocks() -> np.ndarray:
    """Wall time and this thread's CPU time (s): on a shared, loaded CPU the second leaves out
    the time spent waiting for a core."""
    return np.array([time.perf_counter(), time.thread_time()])


def run(src: Path, recording: Path, frames: int) -> dict[str, Any]:
    env = {**os.environ, "PYTHONPATH": f"{src}:{ROOT}", "OMP_NUM_THREADS": "1"}
    with tempfile.NamedTemporaryFile(suffix=".json") as out:
        args = [sys.executable, __file__, "--worker", out.name, "--frames", str(frames)]
        subprocess.run([*args, str(recording)], env=env, check=True, cwd=ROOT)
        return json.loads(Path(out.name).read_text())


def accuracy(motions: list[list[float]], poses: list[list[float]] | None) -> dict[str, float]:
    """As ``studies/scan_odometry.py``: the share of steps with a motion and, against the
    odometry where there is one, their median error."""
    from lidarflow.motion.odometry import metres_to_cells, relative_motions
    from lidarflow.scan import GridSpec
    from studies.scan_odometry import summary

    found = np.asarray(motions, np.float64)
    if poses is None:
        return summary(found, None, np.zeros(len(found), bool))
    moved, known = relative_motions(np.asarray(poses), len(found))
    return summary(found, metres_to_cells(moved, GridSpec().res).astype(np.float64), known)


def load() -> str:
    return subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recordings", type=Path, nargs="*", default=RECORDINGS)
    parser.add_argument("--frames", type=int, default=150)
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--json", type=Path, default=Path("benchmarks/results/scan_odometry.json"))
    parser.add_argument("--worker", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        Path(args.worker).write_text(json.dumps(worker(str(args.recordings[0]), args.frames)))
        return
    loads, results = [load()], {}
    with tempfile.TemporaryDirectory() as tmp:
        archive = subprocess.run(
            ["git", "archive", REFERENCE, "src"], cwd=ROOT, check=True, capture_output=True
        ).stdout
        subprocess.run(["tar", "-x", "-C", tmp], input=archive, check=True)
        codes = {"reference": Path(tmp) / "src", "now": ROOT / "src"}
        for recording in args.recordings:
            runs: dict[str, list[dict[str, Any]]] = {name: [] for name in codes}
            for _ in range(args.rounds):  # alternating, so both see the same load
                for name, src in codes.items():
                    runs[name].append(run(src, recording, args.frames))
            row: dict[str, Any] = {}
            for name, done in runs.items():
                for key in TIMINGS:
                    row[f"{key}_{name}_ms"] = float(np.median([r[f"{key}_ms"] for r in done]))
                row[f"accuracy_{name}"] = accuracy(done[0]["motions"], done[0]["poses"])
            for key in TIMINGS:
                row[f"{key}_ratio"] = row[f"{key}_now_ms"] / row[f"{key}_reference_ms"]
            results[recording.name] = row
            print(recording.name, json.dumps(row, indent=1))
            loads.append(load())
    write_json(
        args.json,
        {
            "benchmark": "scan_odometry",
            "reference": REFERENCE,
            "config": {"frames": args.frames, "rounds": args.rounds, "threads": 1},
            "machine": machine(),
            "load": loads,
            "note": "shared 2-core CPU: the ratios compare runs alternated in the same run",
            "results": results,
        },
    )


if __name__ == "__main__":
    main()
