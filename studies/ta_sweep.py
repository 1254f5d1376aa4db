"""How strong can the temporal-average baseline be? (issue 11)

The verdict compares every model with the temporal average of the last ``N`` maps at a threshold
(``evaluate --ta-window/--ta-threshold``, default 5 / 0.4). This scores every pair of a grid of
``N`` and thresholds on each recording (the streaming evaluation's frames, warm-up and gaps),
beside copy-last, so that the default can be chosen on the development recordings by a stated
rule, and the verdicts checked against the strongest settings.

    python -m studies.ta_sweep ../shared/data/*.bag ../shared/data/*.bag.zip

Writes OUT/ta_sweep.json, its results ``{recording: {"copy_last": [f1, changed_f1],
"N/threshold": [f1, changed_f1], ...}}``, and OUT/ta_sweep.md (each setting's mean F1 and
changed-cell F1 over the recordings).
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from pathlib import Path

from lidarflow.baselines import CopyLast, TemporalAverage
from lidarflow.data import frames_after_gaps, load_any
from lidarflow.evaluate.runner import evaluate_maps
from lidarflow.scan import GridSpec
from studies.harness import development, parse, parser, stem, write_summary

WINDOWS = (2, 3, 4, 5, 6, 7, 8, 10, 12, 15, 20)
THRESHOLDS = (0.2, 0.3, 0.4, 0.5, 0.6, 0.7)


def sweep(
    path: Path, windows: Sequence[int] = WINDOWS, thresholds: Sequence[float] = THRESHOLDS
) -> dict[str, list[float]]:
    """``{"copy_last" or "N/threshold": [f1, changed_f1]}`` on the recording at ``path``,
    scored as `lidarflow evaluate` scores (its warm-up, not across gaps)."""
    recording = load_any(path)
    occupancy, visibility = recording.maps(GridSpec())
    methods: list = [CopyLast()]
    for window, threshold in itertools.product(windows, thresholds):
        method = TemporalAverage(window, threshold)
        method.name = f"{window}/{threshold}"
        methods.append(method)
    gaps = frames_after_gaps(recording.stamps_ns)
    scores = evaluate_maps(occupancy, visibility, methods, gaps=gaps)
    return {name: [s.counts.f1, s.changed.f1] for name, s in scores.items()}


def markdown(result: dict[str, dict[str, list[float]]]) -> str:
    """Each setting's mean F1 / changed-cell F1 over the recordings, best mean F1 first."""
    settings = next(iter(result.values())).keys()
    means = {
        s: [sum(r[s][i] for r in result.values()) / len(result) for i in (0, 1)] for s in settings
    }
    lines = ["| setting | mean F1 | mean changed-cell F1 |", "|---|---|---|"]
    for name, (f1, changed) in sorted(means.items(), key=lambda kv: -kv[1][0]):
        lines.append(f"| {name} | {f1:.4f} | {changed:.4f} |")
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> dict[str, dict[str, list[float]]]:
    p = parser("ta_sweep", __doc__)
    p.add_argument(
        "recordings",
        type=Path,
        nargs="*",
        default=development(),
        help="recordings to sweep (default: the development ones)",
    )
    p.add_argument("--windows", type=int, nargs="+", default=list(WINDOWS))
    p.add_argument("--thresholds", type=float, nargs="+", default=list(THRESHOLDS))
    args = parse(p, argv)  # fmt: skip
    if not args.recordings:
        p.error("no recordings given and none found in the development folder")
    result = {stem(path): sweep(path, args.windows, args.thresholds) for path in args.recordings}
    write_summary(args, "ta_sweep", result, markdown(result))
    return result


if __name__ == "__main__":
    main()
