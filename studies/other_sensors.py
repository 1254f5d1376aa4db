"""Real scans seen through other sensors: does a fold model still beat the baselines?

The recordings lidarflow is judged on come from other robots: other fields of view, range
limits, beam counts and rates. The simulated sensors (`sensor_sweep.py`) vary those on exact
geometry with Gaussian noise; here the development recordings themselves are cut down to what
another sensor would have seen of the same scene, keeping their real noise, dropouts and people:

- ``fov86``: only the beams within 43 degrees of straight ahead (a narrow scanner);
- ``range3.5``: every return beyond 3.5 m becomes no return, ``range_max`` 3.5 m (a hobby LDS);
- ``beams4``: every fourth beam (a coarse scanner: 1.4 degrees between beams on the 270-degree
  Hokuyos, 4 on datmo_overtakes' 360-beam scanner);
- ``rate2``: every second scan (half the rate; the motion per step doubles);
- ``cheap``: 3.5 m, every second beam and every second scan at once (a hobby scanner).

Each view of each recording is scored with the model that never trained on the recording
(``--fold REC=MODEL``; the bundled model has seen every development recording), with
``lidarflow evaluate --online-decision``, beside the three baselines.

    python experiments/other_sensors.py -o runs/other_sensors \\
        --fold ../shared/data/positive_1.bag=runs/loo/p1 ... [--views fov86 range3.5]

Writes OUT/other_sensors.json (added to where it exists; per recording and view: the model's
and the baselines' F1, changed-cell F1 and AP, the verdict and the margins) and
OUT/other_sensors.md.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable
from pathlib import Path

from study import lidarflow, margins, model_and_baselines, split_online, stem, verdict

from lidarflow.data.recording import Recording
from lidarflow.data.sources import load_any
from lidarflow.data.views import SensorView

# name -> the sensor view it scores; "cheap" is the three milder at once (a hobby scanner)
SPECS = {
    "fov86": "fov86",
    "range3.5": "range3.5",
    "beams4": "beams4",
    "rate2": "rate2",
    "cheap": "range3.5+beams2+rate2",
}
VIEWS: dict[str, Callable[[Recording], Recording]] = {
    "recorded": lambda r: r,
    **{name: SensorView.parse(spec).recording for name, spec in SPECS.items()},
}


def fold(spec: str) -> tuple[Path, str]:
    recording, _, model = spec.partition("=")
    if not model:
        raise argparse.ArgumentTypeError(f"--fold wants REC=MODEL, got {spec!r}")
    return Path(recording), model


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--output", type=Path, required=True)
    parser.add_argument("--fold", type=fold, action="append", required=True)
    parser.add_argument("--views", nargs="+", choices=list(VIEWS), default=list(VIEWS))
    args = parser.parse_args()
    args.output.mkdir(parents=True, exist_ok=True)
    summary = args.output / "other_sensors.json"
    # Several runs into one folder add up (one per fold model, say, as each finishes training).
    results: dict[str, dict[str, dict]] = (
        json.loads(summary.read_text()) if summary.exists() else {}
    )
    for source, model in args.fold:
        name = stem(source)
        recording = load_any(source)
        for view in args.views:
            path = args.output / f"{name}__{view}.npz"
            VIEWS[view](recording).save(path)
            report = args.output / f"{name}__{view}.json"
            lidarflow("evaluate", str(path), "--model", model, "--online-decision",
                      "--json", str(report))  # fmt: skip
            methods = json.loads(report.read_text())["recordings"][0]["methods"]
            scores = model_and_baselines(split_online(methods)[0])
            scores["verdict"] = verdict(scores["model"], scores["baselines"])
            f1_margin, changed_margin = margins(scores)
            scores["margins"] = {"f1": round(f1_margin, 4), "changed_f1": round(changed_margin, 4)}
            scores["model_path"] = model
            results.setdefault(name, {})[view] = scores
            summary.write_text(json.dumps(results, indent=1))
    views = [v for v in VIEWS if any(v in by_view for by_view in results.values())]
    (args.output / "other_sensors.md").write_text(table(results, views))
    print(table(results, views))


def table(results: dict[str, dict[str, dict]], views: list[str]) -> str:
    """Markdown: per recording, each view's F1 / changed-cell F1 margins, and the wins."""
    lines = ["| recording | " + " | ".join(views) + " |", "|---" * (len(views) + 1) + "|"]
    wins, scored = dict.fromkeys(views, 0), dict.fromkeys(views, 0)
    for name, by_view in results.items():
        cells = []
        for view in views:
            s = by_view.get(view)
            if s is None:
                cells.append("")
                continue
            wins[view] += s["verdict"] == "wins"
            scored[view] += 1
            m = s["margins"]
            mark = "" if s["verdict"] == "wins" else " **" + s["verdict"] + "**"
            cells.append(f"{m['f1']:+.4f} / {m['changed_f1']:+.4f}{mark}")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    lines.append("| **won** | " + " | ".join(f"{wins[v]} of {scored[v]}" for v in views) + " |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
