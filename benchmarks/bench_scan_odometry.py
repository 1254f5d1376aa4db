"""Per-scan cost of finding the sensor's motion from the scans (robots without odometry), as
ratios to references measured in the same run.

On a simulated drive of each sensor below: :class:`lidarflow.motion.scanmatch.ScanOdometry` fed
the maps only (correlative matching, the reference) and fed the returns too (refined by
point-to-line ICP, what evaluate and a Predictor given scans do), beside ``Predictor.update`` of
the bundled model on the same scans with poses (no scan odometry). Medians over ``--frames``
frames, one thread. Writes JSON (default ``benchmarks/results/scan_odometry.json``).

    python benchmarks/bench_scan_odometry.py [--frames 150]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch
from _output import machine, write_json
from bench_segmentation import median_ms

from lidarflow.motion.icp import recording_points
from lidarflow.motion.scanmatch import ScanOdometry
from lidarflow.predict import Predictor
from lidarflow.scan import GridSpec
from lidarflow.sim import LidarConfig, SimConfig, lidar_preset, simulate

SENSORS = {
    "tim561_270deg_15Hz_811beams": lidar_preset("tim561"),
    "rplidar_360deg_15Hz_3.5m": lidar_preset("rplidar", rate_hz=15.0, range_max=3.5),
    "hokuyo_utm_270deg_1081beams": lidar_preset("hokuyo-utm", rate_hz=5.0, beams=1081),
}


def measure(sensor: LidarConfig, frames: int) -> dict[str, float]:
    """Per-frame medians (ms) on a simulated drive of ``sensor``, and their ratios."""
    grid = GridSpec()
    config = SimConfig(scenario="dynamic", sensor=sensor, episode_frames=frames)
    recording = simulate(frames, seed=3, config=config)
    occupancy = recording.maps(grid)[0]
    points = recording_points(recording)
    maps_only, refined = ScanOdometry(grid.res), ScanOdometry(grid.res)
    predictor = Predictor(threads=1)
    scans = list(recording)
    predictor.update(scans[0], recording.poses[0])  # warm-up
    maps_ms = median_ms(lambda t: maps_only.update(occupancy[t]), frames)
    refined_ms = median_ms(lambda t: refined.update(occupancy[t], points[t]), frames)
    update_ms = median_ms(lambda t: predictor.update(scans[t], recording.poses[t]), frames)
    return {
        "returns_per_scan": float(np.median([len(p) for p in points])),
        "maps_only_ms": maps_ms,
        "refined_ms": refined_ms,
        "predictor_update_with_pose_ms": update_ms,
        "refined_to_maps_only": refined_ms / maps_ms,
        "refined_share_of_update": refined_ms / update_ms,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=150)
    parser.add_argument("--json", type=Path, default=Path("benchmarks/results/scan_odometry.json"))
    args = parser.parse_args()
    torch.set_num_threads(1)
    results: dict[str, dict[str, float]] = {}
    for name, sensor in SENSORS.items():
        results[name] = measure(sensor, args.frames)
        print(name, {k: round(v, 3) for k, v in results[name].items()})
    write_json(
        args.json,
        {
            "benchmark": "scan_odometry",
            "config": {"frames": args.frames, "threads": 1},
            "machine": machine(),
            "note": "shared 2-core CPU: compare the ratios (same run), not absolute times",
            "results": results,
        },
    )


if __name__ == "__main__":
    main()
