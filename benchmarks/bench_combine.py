"""What learning on the stream costs: `Predictor.update` per scan by default (the online
combination deciding the frames 2..K), with ``combine=True`` (it deciding every frame) and with
``learn=True`` (the head learning), each as a ratio to the same Predictor with the model alone
(``combine=False``), measured in the same run (one thread, the bundled model, the sample
recording's scans; no poses, the motion matched from the scans, or with ``--poses`` a slow
drive's, as ``bench_predict.py`` gives them), at ``--horizon`` 1 and K. The variants take
each scan in turn, after an untimed pass and the kernels compiled, so that load on a shared
machine falls on all alike; the medians and the ratios of medians are written to JSON (default
``benchmarks/results/combine.json``), beside the memory the combination holds: ``ratio`` is
the combination's on every frame, ``default_ratio`` the default's, ``learn_ratio`` the head's.

    python benchmarks/bench_combine.py [--scans 150] [--rounds 3] [--horizons 1 8] [--poses]
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch
from _output import machine, write_json
from bench_predict import drive

from lidarflow import compiled
from lidarflow.data import read_bag, sample_bag_path
from lidarflow.predict import Predictor


def per_scan_ms(
    predictors: dict[str, Predictor], scans: list, poses: Sequence, warm: int = 10
) -> dict[str, list[float]]:
    """Each predictor's update time per scan after ``warm`` untimed ones, from a reset, with
    the scan's pose (``None``: none). The predictors take each scan in turn, so that a change
    of the machine's speed falls on all of them alike."""
    for predictor in predictors.values():
        predictor.reset()
    times: dict[str, list[float]] = {name: [] for name in predictors}
    for i, (scan, pose) in enumerate(zip(scans, poses, strict=True)):
        for name, predictor in predictors.items():
            start = time.perf_counter()
            predictor.update(scan, pose)
            if i >= warm:
                times[name].append((time.perf_counter() - start) * 1e3)
    return times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--scans", type=int, default=150)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--horizons", type=int, nargs="+", default=[1, 8])
    parser.add_argument("--poses", action="store_true", help="a slow drive's poses with the scans")
    parser.add_argument(
        "-o", "--output", type=Path, default=Path("benchmarks/results/combine.json")
    )
    args = parser.parse_args()
    torch.set_num_threads(1)
    recording = read_bag(sample_bag_path())
    scans = [recording.scan(i) for i in range(min(args.scans, len(recording)))]
    poses = drive(len(scans)) if args.poses else [None] * len(scans)  # as bench_predict's
    extra = {"check_odometry": False} if args.poses else {}  # the drive is not the scans'
    result: dict = {"machine": machine(), "scans": len(scans), "threads": 1, "horizons": {}}
    result["poses"] = "a slow drive's (bench_predict.drive)" if args.poses else None
    for horizon in args.horizons:
        predictors = {
            # the model alone; the default (the combination from frame 2 on); it on every frame
            "plain": Predictor(horizon=horizon, threads=1, combine=False, **extra),
            "default": Predictor(horizon=horizon, threads=1, **extra),
            "combined": Predictor(horizon=horizon, threads=1, combine=True, **extra),
            "learning": Predictor(horizon=horizon, threads=1, combine=False, learn=True, **extra),
        }
        # An untimed pass first: a fresh install compiles its kernels in the background while
        # the NumPy references serve, and that must not fall inside the timed rounds.
        per_scan_ms(predictors, scans, poses)
        compiled.wait()
        times: dict[str, list[float]] = {name: [] for name in predictors}
        for _ in range(args.rounds):
            for name, some in per_scan_ms(predictors, scans, poses).items():
                times[name] += some
        medians = {k: float(np.median(v)) for k, v in times.items()}
        result["horizons"][str(horizon)] = {
            "median_ms": medians,
            "p99_ms": {k: float(np.percentile(v, 99)) for k, v in times.items()},
            "ratio": medians["combined"] / medians["plain"],
            "default_ratio": medians["default"] / medians["plain"],
            "learn_ratio": medians["learning"] / medians["plain"],
            "combination_bytes": predictors["combined"].combination.nbytes,
        }
        print(horizon, result["horizons"][str(horizon)])
    write_json(args.output, result)


if __name__ == "__main__":
    main()
