"""After a gap in the scans: restart every method, or carry its state across? (gap handling)

A stream of scans can stop for a while. This cuts ``k`` frames out of each development
recording at a few places, streams the bundled model and the baselines over ``--before`` frames,
the gap, and ``--after`` frames, once carrying every method's state across the gap and once
restarting every method after it (as a fresh ``Predictor`` would), and scores the predictions
made after the gap (the step across the gap is scored by neither: it is not a one-step
prediction). Scores are split into the first ``--warmup`` predictions after the gap (which a
streaming evaluation that restarted would not score, its warm-up) and the rest. Carrying won
and is what ``evaluate`` and the ``Predictor`` do (docs/research/gaps/).

    python -m studies.gap_restart -o runs/studies/gap_restart [--splice]

Writes OUT/gap_restart.json (F1 of all and of the changed cells, per case, method and part,
over all recordings and per recording).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from lidarflow.data import load_any
from lidarflow.data.recording import Recording
from studies.harness import development, parse, parser, stem, write_summary
from studies.scoring import add_counts, early_late, f1_table, kept_frames, methods_for, scores_from


def with_gap(recording: Recording, at: int, frames: int, before: int, after: int) -> Recording:
    """``before`` frames up to ``at``, then ``after + 1`` frames from ``at + frames`` on."""
    return kept_frames(
        recording, [*range(at - before, at), *range(at + frames, at + frames + after + 1)]
    )


def spliced(first: Recording, second: Recording, before: int, after: int) -> Recording:
    """The last ``before`` frames of ``first``, then the first ``after + 1`` of ``second``
    (another place after the gap: two sessions in one bag), ``second``'s stamps moved on."""
    a = [first.scan(i) for i in range(len(first) - before, len(first))]
    b = [second.scan(i) for i in range(after + 1)]
    shift = a[-1].stamp_ns + 10**10 - b[0].stamp_ns
    b = [dataclasses.replace(scan, stamp_ns=scan.stamp_ns + shift) for scan in b]
    return Recording.from_scans(a + b, None, second.meta)


def score_after_gap(
    recording: Recording, methods: list, before: int, warmup: int, restart: bool
) -> dict[str, dict]:
    """Counts (``early``: the first ``warmup`` predictions after the gap, ``late``: the rest;
    each ``all`` and ``changed`` cells) per method."""
    if restart:  # every method from a fresh state at the first frame after the gap
        recording, before = recording.slice(before, len(recording)), 0
    return scores_from(recording, methods, early_late(before, warmup))


def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    p = parser("gap_restart", __doc__)
    p.add_argument(
        "--recordings",
        type=Path,
        nargs="+",
        default=development(),
        help="recordings to cut (default: the development ones)",
    )
    p.add_argument("--model", default="bundled")
    p.add_argument("--gaps", type=int, nargs="+", default=[3, 10, 30, 100])
    p.add_argument("--places", type=int, default=3)
    p.add_argument("--before", type=int, default=60)
    p.add_argument("--after", type=int, default=40)
    p.add_argument("--warmup", type=int, default=10)
    p.add_argument(
        "--splice",
        action="store_true",
        help="instead of cutting frames out: each recording after the end of the one before "
        "it in the list (another place after the gap)",
    )
    args = parse(p, argv)  # fmt: skip
    methods = methods_for({args.model: args.model})
    total: dict = {}
    per_recording: dict[str, dict] = {}
    loaded = [load_any(path) for path in args.recordings]
    for i, (path, recording) in enumerate(zip(args.recordings, loaded, strict=True)):
        name = stem(path)
        if args.splice:
            cuts = {"splice": [spliced(loaded[i - 1], recording, args.before, args.after)]}
        else:
            cuts = {}
            for k in args.gaps:
                last = len(recording) - k - args.after - 1
                if last > args.before:  # room for the gap and both sides
                    places = np.linspace(args.before, last, args.places).astype(int)
                    cuts[f"k{k}"] = [
                        with_gap(recording, int(at), k, args.before, args.after) for at in places
                    ]
        for case, recordings in cuts.items():
            for variant in ("carry", "restart"):
                for cut in recordings:
                    got = score_after_gap(
                        cut, methods, args.before, args.warmup, variant == "restart"
                    )
                    add_counts(total, f"{case}_{variant}", got)
                    add_counts(per_recording.setdefault(name, {}), f"{case}_{variant}", got)
            print(name, case, flush=True)
    results = {
        "overall": f1_table(total),
        "recordings": {r: f1_table(t) for r, t in per_recording.items()},
    }
    write_summary(args, "gap_restart", results)
    return results


if __name__ == "__main__":
    main()
