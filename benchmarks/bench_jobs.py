"""``lidarflow evaluate --jobs N`` against ``--jobs 1`` on development recordings (issue 46).

The recordings (default: ``positive_1`` .. ``positive_4`` of ``../shared/data``) are cut to
their first ``--frames`` scans and saved as recordings, so that reading bags is not what is
timed; then ``lidarflow evaluate REC... --warmup 5 -o OUT.json`` (the bundled model beside the
baselines) runs in a fresh process with ``--jobs 1`` and with ``--jobs N``, in turn,
``--repeats`` times. BLAS and OpenMP run on one thread in both (as in a worker; their thread
count changes SSIM's sums in the 10th digit), so the two reports must be the same, byte for
byte. The judged number is the ratio within one run (``speedup``: the median wall time of
``--jobs 1`` over ``--jobs N``'s), beside the machine's load average before and after: the
machine is shared. Where Linux groups the processes of a session for the scheduler
(``autogroup``, recorded), the workers of one command share their session's part of a busy
machine: beside other busy sessions, more workers cannot buy more CPU than that part.
Writes JSON (default ``benchmarks/results/jobs.json``).

    python benchmarks/bench_jobs.py [--frames 60] [--jobs 2] [--repeats 1] [--json PATH] [BAG...]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _output import machine, write_json

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
DATA = ROOT.parent / "shared" / "data"
DEFAULT_BAGS = [DATA / f"positive_{i}.bag" for i in range(1, 5)]


def evaluate_seconds(recordings: list[Path], jobs: int, out: Path) -> float:
    """Wall seconds of one ``lidarflow evaluate`` of ``recordings`` with ``--jobs jobs``."""
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    env.update({"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"})
    argv = [sys.executable, "-m", "lidarflow", "evaluate", *map(str, recordings)]
    argv += ["--warmup", "5", "-o", str(out), "--force", "--jobs", str(jobs)]
    start = time.perf_counter()
    done = subprocess.run(argv, env=env, capture_output=True, text=True, timeout=3600)
    seconds = time.perf_counter() - start
    if done.returncode != 0:
        raise RuntimeError(f"evaluate --jobs {jobs} failed: {done.stderr[-2000:]}")
    return seconds


def _autogroup() -> bool | None:
    """Whether the scheduler shares the CPU between sessions first (Linux autogroup)."""
    try:
        return Path("/proc/sys/kernel/sched_autogroup_enabled").read_text().strip() == "1"
    except OSError:
        return None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("bags", nargs="*", type=Path, default=DEFAULT_BAGS)
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--json", type=Path, default=HERE / "results" / "jobs.json")
    args = parser.parse_args()
    sys.path.insert(0, str(ROOT / "src"))
    from lidarflow.data import load_any

    load_before = os.getloadavg()
    times: dict[int, list[float]] = {1: [], args.jobs: []}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        recordings = [
            load_any(bag).slice(0, args.frames).save(folder / f"{bag.name.split('.')[0]}.npz")
            for bag in args.bags
        ]
        for _ in range(args.repeats):
            for jobs in times:
                times[jobs].append(evaluate_seconds(recordings, jobs, folder / f"j{jobs}.json"))
                print(f"--jobs {jobs}: {times[jobs][-1]:.1f} s")
        reports = [(folder / f"j{jobs}.json").read_bytes() for jobs in times]
        same = reports[0] == reports[1]
    load_after = os.getloadavg()
    medians = {jobs: statistics.median(t) for jobs, t in times.items()}
    speedup = medians[1] / medians[args.jobs]
    print(f"speed-up --jobs {args.jobs} over --jobs 1: {speedup:.2f}x; same report: {same}")
    write_json(
        args.json,
        {
            "machine": machine(),
            "config": {
                "recordings": [b.name for b in args.bags],
                "frames_each": args.frames,
                "command": "lidarflow evaluate REC... --warmup 5 -o OUT.json --jobs J "
                "(bundled model and the baselines; BLAS/OpenMP on one thread)",
                "repeats": args.repeats,
            },
            "load_average_1_5_15_min": {"before": load_before, "after": load_after},
            "sched_autogroup": _autogroup(),
            "seconds": {f"jobs={j}": [round(s, 2) for s in t] for j, t in times.items()},
            "speedup": round(speedup, 3),
            "same_report": same,
        },
    )


if __name__ == "__main__":
    main()
