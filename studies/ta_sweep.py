"""How strong can the temporal-average baseline be? (issue 11)

The verdict compares every model with the temporal average of the last ``N`` maps at a threshold
(``evaluate --ta-window/--ta-threshold``, default 5 / 0.4). This scores every pair of a grid of
``N`` and thresholds on each recording (the streaming evaluation's frames, warm-up and gaps),
beside copy-last, so that the default can be chosen on the development recordings by a stated
rule, and the verdicts checked against the strongest settings.

    python experiments/ta_sweep.py ../shared/data/*.bag --json runs/ta_sweep.json

Writes ``{recording: {"copy_last": [f1, changed_f1], "N/threshold": [f1, changed_f1], ...}}``.
"""

from __future__ import annotations

import argparse
import itertools
import json
from pathlib import Path

from lidarflow.data import frames_after_gaps, load_any
from lidarflow.evaluate.baselines import CopyLast, TemporalAverage
from lidarflow.evaluate.stream import evaluate_maps
from lidarflow.scan import GridSpec

WINDOWS = (2, 3, 4, 5, 6, 7, 8, 10, 12, 15, 20)
THRESHOLDS = (0.2, 0.3, 0.4, 0.5, 0.6, 0.7)


def sweep(path: Path) -> dict[str, list[float]]:
    recording = load_any(path)
    occupancy, visibility = recording.maps(GridSpec())
    methods: list = [CopyLast()]
    for window, threshold in itertools.product(WINDOWS, THRESHOLDS):
        method = TemporalAverage(window, threshold)
        method.name = f"{window}/{threshold}"
        methods.append(method)
    gaps = frames_after_gaps(recording.stamps_ns)
    scores = evaluate_maps(occupancy, visibility, methods, gaps=gaps)
    return {name: [s.counts.f1, s.changed.f1] for name, s in scores.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recordings", type=Path, nargs="+")
    parser.add_argument("--json", type=Path, required=True)
    args = parser.parse_args()
    result = {}
    for path in args.recordings:
        result[path.stem] = sweep(path)
        default = result[path.stem]["5/0.4"]
        print(f"{path.stem}: copy-last {result[path.stem]['copy_last']}, 5/0.4 {default}")
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
