"""A scanner faster than any of the development data or the sensor sweep: 270° 30 m at 40 Hz.

Simulates a static and a driving recording (seed 505, 600 frames, eight people), and each again
without its poses, into OUT (default runs/sensors_40hz/); then evaluate them with

    for f in runs/sensors_40hz/*.npz; do
        lidarflow evaluate $f -m bundled \\
            --json docs/results/accuracy/sensors/hz40/eval_$(basename $f .npz).json
    done
"""

from __future__ import annotations

import argparse
from pathlib import Path

from lidarflow.data import load_recording
from lidarflow.sim import PeopleConfig, SimConfig, lidar_preset, write_simulation


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--output", type=Path, default=Path("runs/sensors_40hz"))
    parser.add_argument("--frames", type=int, default=600)
    parser.add_argument("--seed", type=int, default=505)
    args = parser.parse_args()
    args.output.mkdir(parents=True, exist_ok=True)
    sensor = lidar_preset("hokuyo-utm", rate_hz=40.0, range_max=30.0)
    for scenario in ("static", "dynamic"):
        recording = args.output / f"270deg_40Hz_30m_{scenario}.npz"
        if not recording.exists():
            config = SimConfig(scenario=scenario, sensor=sensor, people=PeopleConfig(count=8))
            write_simulation(recording, args.frames, args.seed, config)
        blind = args.output / f"270deg_40Hz_30m_{scenario}_noposes.npz"
        if not blind.exists():
            without = load_recording(recording)
            without.poses = None
            without.save(blind)
        print(recording, blind)


if __name__ == "__main__":
    main()
