"""A driver that writes "no return" as range_max: does the model still beat the baselines?

Older Gazebo laser plugins, and drivers that clip their readings, report a beam that saw
nothing as ``range_max`` rather than ``+inf``. Read as a return, that draws a ring of occupied
cells at ``range_max`` that stays put in the sensor's frame however the robot moves: copy-last
gets it right for free, and a model that moves the map with the robot's motion moves the ring
too.
This simulates the sensors of `sensor_sweep.py` whose ``range_max`` lies inside the grid, each
static and driving, writes a copy of each recording with every ``+inf`` replaced by its scan's
``range_max``, and evaluates the model on both (`lidarflow evaluate`, with the simulator's
odometry). With ``--written-as zero`` the copy writes no return as ``0.0`` instead, as
TurtleBot3's LDS driver does (read as unknown beams, by the design notes' rule); with
``--written-as noisy`` as ``range_max`` plus 1 cm Gaussian noise, clipped to ``range_max`` (as
Gazebo versions that add noise before clipping do: half the ring just under ``range_max``).

    python experiments/range_max_ring.py -o runs/range_max_ring [--model bundled] [--seed 202]

Writes OUT/range_max_ring.json and .md.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from sensor_sweep import SENSORS
from study import lidarflow, model_and_baselines, verdict

from lidarflow.data import load_recording
from lidarflow.sim import PeopleConfig, SimConfig, lidar_preset, write_simulation

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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--output", type=Path, required=True)
    parser.add_argument("--model", default="bundled")
    parser.add_argument("--frames", type=int, default=300)
    parser.add_argument("--seed", type=int, default=202)
    parser.add_argument("--written-as", choices=("range_max", "zero", "noisy"), default="range_max")
    args = parser.parse_args()
    args.output.mkdir(parents=True, exist_ok=True)
    study: dict[str, dict] = {}
    for name in RING_SENSORS:
        preset, fields = SENSORS[name]
        for scenario in ("static", "dynamic"):
            plain = args.output / f"{name}_{scenario}.npz"
            if not plain.exists():
                config = SimConfig(
                    scenario=scenario,
                    sensor=lidar_preset(preset, **fields),
                    people=PeopleConfig(count=8),
                )
                write_simulation(plain, args.frames, args.seed, config)
            ringed = args.output / f"{name}_{scenario}_{args.written_as}.npz"
            share = write_ring(plain, ringed, args.written_as)
            row: dict[str, object] = {"no_return_share": share}
            for kind, recording in (("inf", plain), (args.written_as, ringed)):
                report = recording.with_suffix(".json")
                lidarflow("evaluate", str(recording), "--model", args.model, "--json", str(report))
                methods = json.loads(report.read_text())["recordings"][0]["methods"]
                scores = model_and_baselines(methods)
                row[kind] = {**scores, "verdict": verdict(scores["model"], scores["baselines"])}
            study[f"{name}/{scenario}"] = row
    lines = [
        "| sensor / scenario | no return | written +inf: model / copy-last F1, verdict "
        f"| written {args.written_as}: model / copy-last F1, verdict |",
        "|---|---|---|---|",
    ]
    for key, row in study.items():
        cells = [
            f"{r['model']['f1']:.3f} / {r['baselines']['copy_last']['f1']:.3f}, {r['verdict']}"
            for r in (row["inf"], row[args.written_as])
        ]
        lines.append(f"| {key} | {row['no_return_share']:.0%} | " + " | ".join(cells) + " |")
    name = "range_max_ring" if args.written_as == "range_max" else f"written_as_{args.written_as}"
    (args.output / f"{name}.json").write_text(json.dumps(study, indent=2) + "\n")
    (args.output / f"{name}.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
