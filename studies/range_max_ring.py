"""A driver that writes "no return" as range_max: does the model still beat the baselines?

Older Gazebo laser plugins, and drivers that clip their readings, report a beam that saw
nothing as ``range_max`` rather than ``+inf``. Read as a return, that draws a ring of occupied
cells at ``range_max`` that stays put in the sensor's frame however the robot moves: copy-last
gets it right for free, and a model that moves the map with the robot's motion moves the ring
too.
This simulates the sensors of ``studies.sensor_sweep`` whose ``range_max`` lies inside the grid,
each static and driving, writes a copy of each recording with every ``+inf`` replaced by its
scan's ``range_max``, and evaluates the model on both (`lidarflow evaluate`, with the
simulator's odometry). With ``--written-as zero`` the copy writes no return as ``0.0`` instead,
as TurtleBot3's LDS driver does (read as unknown beams, by the design notes' rule); with
``--written-as noisy`` as ``range_max`` plus 1 cm Gaussian noise, clipped to ``range_max`` (as
Gazebo versions that add noise before clipping do: half the ring just under ``range_max``).

    python -m studies.range_max_ring -o runs/studies/range_max_ring [--model bundled] [--seed 202]

Writes OUT/range_max_ring.json and .md (with --written-as zero / noisy:
OUT/written_as_<zero|noisy>.*).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from lidarflow.data import load_recording
from studies.harness import parse, parser, write_summary
from studies.sensor_sweep import SCENARIOS, scored, simulated

#: the sweep's sensors whose range_max (3.5 m, 5.6 m) draws the ring inside the 10 m grid
RING_SENSORS = ("86deg_5Hz_3.5m", "180deg_15Hz_5.6m", "360deg_15Hz_3.5m")


def write_ring(source: Path, target: Path, written_as: str = "range_max") -> float:
    """Copy ``source`` with every ``+inf`` range written as its scan's ``range_max`` (or as
    ``0.0``: ``written_as="zero"``; ``range_max`` plus 1 cm noise, clipped: ``"noisy"``); the
    share of beams so rewritten."""
    recording = load_recording(source)
    per_beam = np.repeat(recording.range_max, np.diff(recording.offsets)).astype(np.float32)
    noise = np.random.default_rng(0).normal(0.0, 0.01, per_beam.shape).astype(np.float32)
    value = {
        "range_max": per_beam,
        "zero": np.float32(0.0),
        "noisy": np.minimum(per_beam + noise, per_beam),
    }[written_as]
    ring = np.isposinf(recording.ranges)
    recording.ranges = np.where(ring, value, recording.ranges).astype(np.float32)
    recording.save(target)
    return float(ring.mean())


def markdown(study: dict[str, dict[str, Any]], written_as: str) -> str:
    lines = [
        "| sensor / scenario | no return | written +inf: model / copy-last F1, verdict "
        f"| written {written_as}: model / copy-last F1, verdict |",
        "|---|---|---|---|",
    ]
    for key, row in study.items():
        cells = [
            f"{r['model']['f1']:.3f} / {r['baselines']['copy_last']['f1']:.3f}, {r['verdict']}"
            for r in (row["inf"], row[written_as])
        ]
        lines.append(f"| {key} | {row['no_return_share']:.0%} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> dict[str, dict[str, Any]]:
    p = parser("range_max_ring", __doc__)
    p.add_argument("--model", default="bundled")
    p.add_argument("--frames", type=int, default=300)
    p.add_argument("--seed", type=int, default=202)
    p.add_argument("--sensors", nargs="+", choices=RING_SENSORS, default=list(RING_SENSORS))
    p.add_argument("--written-as", choices=("range_max", "zero", "noisy"), default="range_max")
    args = parse(p, argv)
    args.output.mkdir(parents=True, exist_ok=True)
    study: dict[str, dict[str, Any]] = {}
    for sensor in args.sensors:
        for scenario in SCENARIOS:
            plain = args.output / f"{sensor}_{scenario}.npz"
            simulated(plain, sensor, scenario, args.frames, args.seed)
            ringed = args.output / f"{sensor}_{scenario}_{args.written_as}.npz"
            row: dict[str, Any] = {"no_return_share": write_ring(plain, ringed, args.written_as)}
            row["inf"] = scored(plain, args.model)
            row[args.written_as] = scored(ringed, args.model)
            study[f"{sensor}/{scenario}"] = row
    name = "range_max_ring" if args.written_as == "range_max" else f"written_as_{args.written_as}"
    write_summary(args, name, study, markdown(study, args.written_as))
    return study


if __name__ == "__main__":
    main()
