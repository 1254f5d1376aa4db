"""How well is the sensor's motion found from the scans alone? (issue 11, robots without odometry)

For each recording the motion of every frame step is found twice, as `lidarflow evaluate` finds it
for a model that may run without poses: from the maps only (correlative matching,
:func:`lidarflow.motion.scanmatch.match_maps`) and refined on the returns
(:class:`lidarflow.motion.scanmatch.ScanOdometry` given the points, the default). Where the
recording has poses (odometry, or the simulator's truth) both are compared with them: the share
of steps with a motion, and the median error of those in cells and degrees. Where it has none
(standing still, or a car without odometry) the share of steps reported says how often the
platform was taken to move.

    python -m studies.scan_odometry -o runs/studies/scan_odometry \\
        ../shared/data/general_tracking_moving_1.bag.zip ../shared/data/datmo_overtakes.bag \\
        ../shared/data/{positive_1,positive_4,demo_stationary_simple_environment}.bag \\
        runs/studies/sensor_sweep/360deg_15Hz_3.5m_dynamic.npz

Writes OUT/motions.json (per recording: frames, whether it has poses, and for each way the
share of steps with a motion and the median errors) and OUT/motions.md.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from lidarflow.data import load_any
from lidarflow.motion.icp import recording_points
from lidarflow.motion.odometry import metres_to_cells, relative_motions
from lidarflow.motion.scanmatch import scan_motions
from lidarflow.scan import GridSpec
from studies.harness import parse, parser, write_summary


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


def markdown(results: dict[str, dict[str, Any]]) -> str:
    lines = [
        "| recording | poses | way | steps with a motion | median error (cells) | "
        "median error (deg) |",
        "|---|---|---|---|---|---|",
    ]
    for name, row in results.items():
        for way in ("maps_only", "refined_on_returns"):
            s = row[way]
            cells = [
                f"{s[k]:.3f}" if k in s else "-" for k in ("median_error_cells", "median_error_deg")
            ]
            lines.append(
                f"| {name} | {'yes' if row['has_poses'] else 'no'} | {way} | "
                f"{s['steps_with_motion']:.2f} | " + " | ".join(cells) + " |"
            )
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> dict[str, dict[str, Any]]:
    p = parser("scan_odometry", __doc__)
    p.add_argument("recordings", type=Path, nargs="+")
    args = parse(p, argv)
    grid = GridSpec()
    results: dict[str, dict[str, Any]] = {}
    for path in args.recordings:
        recording = load_any(path)
        occupancy = recording.maps(grid)[0]
        true, known = None, np.zeros(len(recording), bool)
        if recording.has_poses:
            motions, known = relative_motions(recording.poses, len(recording))
            true = metres_to_cells(motions, grid.res).astype(np.float64)
        refined = scan_motions(occupancy, recording_points(recording), grid.res)
        results[path.name] = {
            "frames": len(recording),
            "has_poses": recording.has_poses,
            "maps_only": summary(scan_motions(occupancy).astype(np.float64), true, known),
            "refined_on_returns": summary(refined.astype(np.float64), true, known),
        }
    args.grid = grid.to_dict()
    write_summary(args, "motions", results, markdown(results))
    return results


if __name__ == "__main__":
    main()
