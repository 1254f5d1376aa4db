"""A 360-degree scanner turned on its robot (an RPLidar mounted with its cable forward, say).

The grid covers the half-plane in front of the scanner's own x axis, so a scanner turned by
``--yaw`` on a driving robot sees the world stream past at another angle: facing backwards, the
scene recedes from the sensor instead of coming at it. For a full-circle scan turning the
scanner is exact after the fact: each scan's bearings move by ``-yaw`` and each pose's heading
by ``+yaw``. This writes such a copy of each recording (with its poses, and without: motion from
the scans) and evaluates the model on it (`lidarflow evaluate`).

    python experiments/sensor_sweep.py -o runs/s606 --seed 606   # the recordings
    python experiments/turned_scanner.py runs/s606/360deg_*_dynamic.npz -o runs/turned \\
        [--yaw 180] [--model bundled]

Writes OUT/turned.json and .md.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np
from study import BASELINES, lidarflow, model_and_baselines, stem, verdict

from lidarflow.data import load_recording


def write_turned(source: Path, target: Path, yaw: float, poses: bool) -> None:
    """Copy ``source`` (a full-circle recording) as seen by its scanner turned by ``yaw``
    radians on the robot; without the simulator's ground truth, which is in the old frame."""
    recording = load_recording(source)
    fov = np.abs(recording.angle_increment) * np.diff(recording.offsets)
    if np.any(fov < 2 * math.pi - 1e-3):
        raise SystemExit(f"{source}: not a full-circle scan; turning it would change the view")
    recording.angle_min = recording.angle_min - yaw
    if recording.poses is not None and poses:
        recording.poses = recording.poses.copy()
        recording.poses[:, 2] = np.angle(np.exp(1j * (recording.poses[:, 2] + yaw)))
    else:
        recording.poses = None
    recording.extras = {}
    recording.meta.pop("grid", None)
    recording.save(target)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recordings", type=Path, nargs="+")
    parser.add_argument("-o", "--output", type=Path, required=True)
    parser.add_argument("--yaw", type=float, default=180.0, help="degrees, counter-clockwise")
    parser.add_argument("--model", default="bundled")
    args = parser.parse_args()
    args.output.mkdir(parents=True, exist_ok=True)
    study: dict[str, dict] = {}
    for source in args.recordings:
        for poses in (True, False):
            key = f"{stem(source)}{'' if poses else '_noposes'}"
            turned = args.output / f"{key}.npz"
            write_turned(source, turned, math.radians(args.yaw), poses)
            report = turned.with_suffix(".json")
            lidarflow("evaluate", str(turned), "--model", args.model, "--json", str(report))
            methods = json.loads(report.read_text())["recordings"][0]["methods"]
            scores = model_and_baselines(methods)
            study[key] = {**scores, "verdict": verdict(scores["model"], scores["baselines"])}
    lines = [
        f"| recording, scanner turned {args.yaw:g} deg | {args.model} F1 / changed F1 | "
        + " | ".join(BASELINES)
        + " | verdict |",
        "|---|---|---|---|---|---|",
    ]
    for key, r in study.items():
        cells = [f"{r['model']['f1']:.3f} / {r['model']['changed_f1']:.3f}"]
        cells += [f"{r['baselines'][b]['f1']:.3f} / {r['baselines'][b]['changed_f1']:.3f}"
                  for b in BASELINES]  # fmt: skip
        lines.append(f"| {key} | " + " | ".join(cells) + f" | {r['verdict']} |")
    (args.output / "turned.json").write_text(json.dumps(study, indent=2) + "\n")
    (args.output / "turned.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
