"""Real scans seen through other sensors: does a fold model still beat the baselines?

The recordings lidarflow is judged on come from other robots: other fields of view, range
limits, beam counts and rates. The simulated sensors (``studies.sensor_sweep``) vary those on exact
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
both decision rules (as ``lidarflow evaluate --online-decision``), beside the three
baselines; the model's own rule is judged.

    python -m studies.other_sensors -o runs/studies/other_sensors \\
        --fold ../shared/data/positive_1.bag=runs/studies/leave_one_out/head/positive_1/run \\
        ... [--views fov86 range3.5]

Writes OUT/<recording>__<view>.json (each evaluation), OUT/other_sensors.json (added to where it
exists; per recording and view: the model's
and the baselines' F1, changed-cell F1 and AP, the verdict and the margins) and
OUT/other_sensors.md.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

from lidarflow.data.recording import Recording
from lidarflow.data.sources import load_any
from studies.harness import fold, judged, parse, parser, read_json, stem, write_json, write_summary
from studies.scoring import evaluate_one
from studies.sensor_views import SensorView

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


def main(argv: Sequence[str] | None = None) -> dict[str, dict[str, dict]]:
    p = parser("other_sensors", __doc__)
    p.add_argument(
        "--fold",
        type=fold,
        action="append",
        required=True,
        metavar="REC=MODEL",
        help="a recording and the model that never trained on it (repeatable)",
    )
    p.add_argument("--views", nargs="+", choices=list(VIEWS), default=list(VIEWS))
    args = parse(p, argv)  # fmt: skip
    summary = args.output / "other_sensors.json"
    # Several runs into one folder add up (one per fold model, say, as each finishes training).
    results: dict[str, dict[str, dict]] = read_json(summary)["results"] if summary.exists() else {}
    for source, model in args.fold:
        name = stem(source)
        recording = load_any(source)
        for view in args.views:
            methods = evaluate_one(VIEWS[view](recording), f"{name}__{view}", model, online=True)
            write_json(args.output / f"{name}__{view}.json", methods)
            results.setdefault(name, {})[view] = {**judged(methods), "model_path": model}
    views = [v for v in VIEWS if any(v in by_view for by_view in results.values())]
    write_summary(args, "other_sensors", results, table(results, views))
    return results


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
