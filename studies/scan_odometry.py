"""How well is the sensor's motion found from the scans alone? (issue 11, robots without odometry)

For each recording the motion of every frame step is found twice, as `lidarflow evaluate` finds it
for a model that may run without poses: from the maps only (correlative matching,
:func:`lidarflow.motion.scanmatch.match_maps`) and refined on the returns
(:class:`lidarflow.motion.scanmatch.ScanOdometry` given the points, the default). Where the
recording has poses (odometry, or the simulator's truth) both are compared with them: the share
of steps with a motion, and the median error of those in cells and degrees. Where it has none
(standing still, or a car without odometry) the share of steps reported says how often the
platform was taken to move.

    python experiments/scan_odometry.py --json docs/results/accuracy/scan_odometry/motions.json \\
        ../shared/data/general_tracking_moving_1.bag.zip ../shared/data/datmo_overtakes.bag \\
        ../shared/data/{positive_1,positive_4,demo_stationary_simple_environment}.bag \\
        runs/sensors_s202/360deg_15Hz_3.5m_dynamic.npz
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from lidarflow.data import load_any
from lidarflow.motion.icp import recording_points
from lidarflow.motion.odometry import metres_to_cells, relative_motions
from lidarflow.motion.scanmatch import scan_motions
from lidarflow.scan import GridSpec


def summary(found: np.ndarray, true: np.ndarray | None, known: np.ndarray) -> dict[str, float]:
    """Share of steps with a motion and, against ``true`` where ``known``, their median error."""
    steps = np.isfinite(found[1:, 0])
    out = {"steps_with_motion": float(steps.mean())}
    if true is not None and known[1:].any():
        both = np.isfinite(found[:, 0]) & known
        if both.any():
            error = found[both] - true[both]
            out["median_error_cells"] = float(np.median(np.hypot(error[:, 0], error[:, 1])))
            out["median_error_deg"] = float(np.degrees(np.median(np.abs(error[:, 2]))))
        out["median_true_motion_cells"] = float(np.median(np.hypot(true[known, 0], true[known, 1])))
        out["median_true_turn_deg"] = float(np.degrees(np.median(np.abs(true[known, 2]))))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recordings", type=Path, nargs="+")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    grid = GridSpec()
    results: dict[str, dict] = {}
    for path in args.recordings:
        recording = load_any(path)
        occupancy = recording.maps(grid)[0]
        true, known = None, np.zeros(len(recording), bool)
        if recording.has_poses:
            motions, known = relative_motions(recording.poses, len(recording))
            true = metres_to_cells(motions, grid.res).astype(np.float64)
        row = {
            "frames": len(recording),
            "has_poses": recording.has_poses,
            "maps_only": summary(scan_motions(occupancy).astype(np.float64), true, known),
            "refined_on_returns": summary(
                scan_motions(occupancy, recording_points(recording), grid.res).astype(np.float64),
                true,
                known,
            ),
        }
        results[path.name] = row
        print(path.name, json.dumps({k: row[k] for k in ("maps_only", "refined_on_returns")}))
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        payload = {"grid": grid.to_dict(), "results": results}
        args.json.write_text(json.dumps(payload, indent=2) + "\n")


if __name__ == "__main__":
    main()
