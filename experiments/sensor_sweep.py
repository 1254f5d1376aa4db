"""Does a model still beat the baselines on sensors it was not trained with? (issue 11)

Simulates short static and driving recordings with LiDARs of other fields of view (86° to
360°), rates (5 to 15 Hz), beam counts and range limits (3.5 to 12 m) than the development
data, all rasterized to the same 100 x 100 x 0.1 m grid, evaluates the model beside the
baselines (`lidarflow evaluate`, streaming, 10 warm-up frames) and writes the per-sensor verdict
(the rule of experiments/leave_one_out.py).

    python experiments/sensor_sweep.py -o runs/sensors [--model bundled] [--frames 300]

Writes OUT/sensors.json and OUT/sensors.md.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from study import BASELINES, lidarflow, model_and_baselines, verdict

from lidarflow.sim import PeopleConfig, SimConfig, lidar_preset, write_simulation

# name -> (preset, fields replaced); none of these is a training preset as it stands.
SENSORS: dict[str, tuple[str, dict[str, object]]] = {
    "86deg_5Hz_3.5m": (
        "hokuyo-urg",
        {"fov_deg": 86.0, "beams": 245, "rate_hz": 5.0, "range_max": 3.5},
    ),
    "180deg_15Hz_5.6m": ("hokuyo-urg", {"rate_hz": 15.0}),
    "270deg_5Hz_12m": ("hokuyo-utm", {"rate_hz": 5.0, "range_max": 12.0, "beams": 1081}),
    "360deg_5Hz_12m": ("rplidar", {"rate_hz": 5.0, "range_max": 12.0, "beams": 720}),
    "360deg_15Hz_3.5m": ("rplidar", {"rate_hz": 15.0, "range_max": 3.5}),
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--output", type=Path, required=True)
    parser.add_argument("--model", default="bundled")
    parser.add_argument("--frames", type=int, default=300)
    parser.add_argument("--seed", type=int, default=101, help="not a seed of the training sets")
    args = parser.parse_args()
    args.output.mkdir(parents=True, exist_ok=True)
    study: dict[str, dict] = {}
    for name, (preset, fields) in SENSORS.items():
        for scenario in ("static", "dynamic"):
            key = f"{name}/{scenario}"
            recording = args.output / f"{name}_{scenario}.npz"
            report = args.output / f"{name}_{scenario}.json"
            if not recording.exists():
                config = SimConfig(
                    scenario=scenario,
                    sensor=lidar_preset(preset, **fields),
                    people=PeopleConfig(count=8),
                )
                write_simulation(recording, args.frames, args.seed, config)
            if not report.exists():
                lidarflow("evaluate", str(recording), "--model", args.model, "--json", str(report))
            scores = model_and_baselines(json.loads(report.read_text())["recordings"][0]["methods"])
            study[key] = {**scores, "verdict": verdict(scores["model"], scores["baselines"])}
    lines = [
        f"| sensor / scenario | {args.model} F1 / changed F1 | copy last | temporal average | "
        "constant velocity | verdict |",
        "|---|---|---|---|---|---|",
    ]
    for key, r in study.items():
        cells = [f"{r['model']['f1']:.3f} / {r['model']['changed_f1']:.3f}"]
        cells += [
            f"{r['baselines'][b]['f1']:.3f} / {r['baselines'][b]['changed_f1']:.3f}"
            for b in BASELINES
        ]
        lines.append(f"| {key} | " + " | ".join(cells) + f" | {r['verdict']} |")
    wins = sum(r["verdict"] == "wins" for r in study.values())
    lines.append(f"| **wins on {wins} of {len(study)}** | | | | | |")
    (args.output / "sensors.json").write_text(json.dumps(study, indent=2) + "\n")
    (args.output / "sensors.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
