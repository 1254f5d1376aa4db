"""Does a model still beat the baselines on sensors it was not trained with? (issue 11)

Simulates short static and driving recordings with LiDARs of other fields of view (86° to
360°), rates (5 to 15 Hz), beam counts and range limits (3.5 to 12 m) than the development
data, all rasterized to the same 100 x 100 x 0.1 m grid, evaluates the model beside the
baselines (`lidarflow evaluate`, streaming, 10 warm-up frames) and writes the per-sensor verdict
(the rule of experiments/leave_one_out.py).

    python experiments/sensor_sweep.py -o runs/sensors [--model bundled] [--frames 300]

The simulated platform's poses are exact odometry, which an ego-motion model uses; with
``--without-poses`` every recording is evaluated with its poses removed instead (a robot without
odometry). Beside an ego-motion model the table shows copy_last_ego (the last map moved by the
odometry) as a reference; verdicts count the three baselines only.

Writes OUT/sensors.json and OUT/sensors.md (with --without-poses: OUT/sensors_noposes.*).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from study import BASELINES, lidarflow, model_and_baselines, verdict

from lidarflow.data import load_recording
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
    parser.add_argument(
        "--without-poses", action="store_true", help="evaluate the recordings without their poses"
    )
    parser.add_argument(
        "--noise", type=float, help="every sensor's range noise std (m), instead of its preset's"
    )
    parser.add_argument(
        "--dropout", type=float, help="every sensor's chance of a beam dropping out, ditto"
    )
    args = parser.parse_args()
    noise = {} if args.noise is None else {"noise_std": args.noise}
    noise |= {} if args.dropout is None else {"dropout_prob": args.dropout}
    args.output.mkdir(parents=True, exist_ok=True)
    study: dict[str, dict] = {}
    for name, (preset, fields) in SENSORS.items():
        for scenario in ("static", "dynamic"):
            key = f"{name}/{scenario}"
            recording = args.output / f"{name}_{scenario}.npz"
            suffix = "_noposes" if args.without_poses else ""
            report = args.output / f"{name}_{scenario}{suffix}.json"
            if not recording.exists():
                config = SimConfig(
                    scenario=scenario,
                    sensor=lidar_preset(preset, **fields, **noise),
                    people=PeopleConfig(count=8),
                )
                write_simulation(recording, args.frames, args.seed, config)
            evaluated = recording
            if args.without_poses:
                evaluated = args.output / f"{name}_{scenario}_noposes.npz"
                if not evaluated.exists():
                    blind = load_recording(recording)
                    blind.poses = None
                    blind.save(evaluated)
            if not report.exists():
                lidarflow("evaluate", str(evaluated), "--model", args.model, "--json", str(report))
            scores = model_and_baselines(json.loads(report.read_text())["recordings"][0]["methods"])
            study[key] = {**scores, "verdict": verdict(scores["model"], scores["baselines"])}
    ego = any("copy_last_ego" in r.get("references", {}) for r in study.values())
    lines = [
        f"| sensor / scenario | {args.model} F1 / changed F1 | copy last | temporal average | "
        "constant velocity |" + (" copy last ego (reference) |" if ego else "") + " verdict |",
        "|---|---|---|---|---|" + ("---|" if ego else "") + "---|",
    ]
    for key, r in study.items():
        cells = [f"{r['model']['f1']:.3f} / {r['model']['changed_f1']:.3f}"]
        scores = [r["baselines"][b] for b in BASELINES]
        if ego:
            scores.append(r.get("references", {}).get("copy_last_ego"))
        cells += ["-" if s is None else f"{s['f1']:.3f} / {s['changed_f1']:.3f}" for s in scores]
        lines.append(f"| {key} | " + " | ".join(cells) + f" | {r['verdict']} |")
    wins = sum(r["verdict"] == "wins" for r in study.values())
    lines.append(f"| **wins on {wins} of {len(study)}** | | | | |" + (" |" if ego else "") + " |")
    name = "sensors_noposes" if args.without_poses else "sensors"
    (args.output / f"{name}.json").write_text(json.dumps(study, indent=2) + "\n")
    (args.output / f"{name}.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
