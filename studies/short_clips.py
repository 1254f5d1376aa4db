"""Does a fold model win short clips of the recording it never saw? (issue 11)

A recording someone brings may be a few seconds long. The online decision learns its offsets
from the stream (evaluate/online.py), so its first frames are decided on little evidence. This
cuts the first ``N`` frames of each recording, evaluates the fold model that did not train on
it (`lidarflow evaluate`, 10 warm-up frames), and writes the verdicts beside those of the whole
recording's first frames.

    python experiments/short_clips.py -o runs/short_clips --frames 60 120 \\
        --fold ../shared/data/positive_1.bag=runs/loo/subcell_p1/head_subcell/positive_1/run \\
        [--fold RECORDING=RUN ...]

Writes OUT/short_clips.json and .md.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from study import lidarflow, margins, model_and_baselines, stem, verdict

from lidarflow.data import load_any


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--output", type=Path, required=True)
    parser.add_argument("--frames", type=int, nargs="+", default=[60, 120])
    parser.add_argument(
        "--fold", action="append", required=True, metavar="RECORDING=RUN",
        help="a recording and the fold model that never trained on it",
    )  # fmt: skip
    args = parser.parse_args()
    args.output.mkdir(parents=True, exist_ok=True)
    study: dict[str, dict] = {}
    for fold in args.fold:
        source, run = (Path(p) for p in fold.split("=", 1))
        recording = load_any(source)
        for n in args.frames:
            clip = args.output / f"{stem(source)}_first{n}.npz"
            recording.slice(0, min(n, len(recording))).save(clip)
            report = clip.with_suffix(".json")
            lidarflow("evaluate", str(clip), "--model", str(run), "--json", str(report))
            scores = model_and_baselines(json.loads(report.read_text())["recordings"][0]["methods"])
            f1_margin, changed_margin = margins(scores)
            study[f"{stem(source)}/first {n}"] = {
                **scores,
                "f1_margin": f1_margin,
                "changed_f1_margin": changed_margin,
                "verdict": verdict(scores["model"], scores["baselines"]),
            }
    lines = ["| clip | F1 margin | changed-cell F1 margin | verdict |", "|---|---|---|---|"]
    for key, r in study.items():
        lines.append(
            f"| {key} | {r['f1_margin']:+.4f} | {r['changed_f1_margin']:+.4f} | {r['verdict']} |"
        )
    wins = sum(r["verdict"] == "wins" for r in study.values())
    lines.append(f"| **wins {wins} of {len(study)}** | | | |")
    (args.output / "short_clips.json").write_text(json.dumps(study, indent=2) + "\n")
    (args.output / "short_clips.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
