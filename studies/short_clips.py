"""Does a fold model win short clips of the recording it never saw? (issue 11)

A recording someone brings may be a few seconds long. The online decision learns its offsets
from the stream (the online decision), so its first frames are decided on little evidence. This
cuts the first ``N`` frames of each recording, evaluates the fold model that did not train on
it (`lidarflow evaluate`, 10 warm-up frames), and writes the verdicts beside those of the whole
recording's first frames.

    python -m studies.short_clips -o runs/studies/short_clips --frames 60 120 \\
        --fold ../shared/data/positive_1.bag=runs/studies/leave_one_out/head/positive_1/run \\
        [--fold RECORDING=RUN ...]

Writes OUT/short_clips.json and .md.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from lidarflow.data import load_any
from studies.harness import fold, judged, parse, parser, stem, write_json, write_summary
from studies.scoring import evaluate_one


def markdown(study: dict[str, dict[str, Any]]) -> str:
    lines = ["| clip | F1 margin | changed-cell F1 margin | verdict |", "|---|---|---|---|"]
    for key, r in study.items():
        m = r["margins"]
        lines.append(f"| {key} | {m['f1']:+.4f} | {m['changed_f1']:+.4f} | {r['verdict']} |")
    wins = sum(r["verdict"] == "wins" for r in study.values())
    lines.append(f"| **wins {wins} of {len(study)}** | | | |")
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> dict[str, dict[str, Any]]:
    p = parser("short_clips", __doc__)
    p.add_argument("--frames", type=int, nargs="+", default=[60, 120])
    p.add_argument(
        "--fold",
        type=fold,
        action="append",
        required=True,
        metavar="RECORDING=RUN",
        help="a recording and the fold model that never trained on it",
    )
    args = parse(p, argv)  # fmt: skip
    study: dict[str, dict[str, Any]] = {}
    for source, run in args.fold:
        recording = load_any(source)
        for n in args.frames:
            clip = recording.slice(0, min(n, len(recording)))
            methods = evaluate_one(clip, f"{stem(source)}_first{n}", run)
            write_json(args.output / f"{stem(source)}_first{n}.json", methods)
            study[f"{stem(source)}/first {n}"] = judged(methods)
    write_summary(args, "short_clips", study, markdown(study))
    return study


if __name__ == "__main__":
    main()
