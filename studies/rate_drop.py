"""A scanner that slows down mid-stream (a driver gone from 10 to 5 Hz): the frames after it.

At ``--places`` places of a driving recording, keeps ``--before`` frames up to the place and
then every ``--every``-th frame, ``--after`` of them (the same drive seen at a lower rate from
there on), streams the bundled model and the baselines over it, and scores the first
``--early`` predictions after the change and the rest (F1 / changed-cell F1). The first step
at the new rate looks like a dropped scan, and the ones after it are as long: what the guess of
the next motion makes of them is what this measures
(``lidarflow.motion.pacing.paces_after_long_steps``). With ``--drops``, the other side: each scan of
the whole drive after ``--before`` dropped at random, scored after one long step, after two in
a row, and after a typical one (a rule that took two long steps for a slower rate would guess
the next step long where it is mostly typical).

    python experiments/rate_drop.py --json docs/results/gaps/rate_drop.json
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
from study import add_counts, early_late, f1_table, kept_frames, scores_from

from lidarflow.cli.scoring import methods_and_config
from lidarflow.data import load_any
from lidarflow.data.gaps import PACE_ABOVE
from lidarflow.data.recording import Recording
from lidarflow.sim import SimConfig, simulate

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def slowed(recording: Recording, at: int, every: int, before: int, after: int) -> Recording:
    """``before`` frames up to ``at``, then every ``every``-th frame from ``at`` on, ``after``
    of them."""
    return kept_frames(recording, [*range(at - before, at), *range(at, at + every * after, every)])


def dropped(recording: Recording, start: int, p: float, seed: int) -> Recording:
    """Every frame up to ``start``, then each frame kept with probability ``1 - p``."""
    rng = np.random.default_rng(seed)
    kept = [i for i in range(len(recording)) if i < start or rng.random() >= p]
    return kept_frames(recording, kept)


def after_drops(recording: Recording, start: int) -> Callable[[int], str | None]:
    """Parts of :func:`study.scores_from` for a recording with scans dropped: predictions made
    at a frame after one long step (``after_one``), after two in a row (``after_two``), or
    after a typical step (``after_none``), from ``start`` on. Long: over 1.5 typical steps."""
    steps = np.diff(np.asarray(recording.stamps_ns, dtype=np.float64))
    long = np.r_[False, steps > PACE_ABOVE * float(np.median(steps))]

    def part(t: int) -> str | None:
        if t < start:
            return None
        return "after_two" if long[t] and long[t - 1] else "after_one" if long[t] else "after_none"

    return part


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--places", type=int, default=4)
    parser.add_argument("--before", type=int, default=60)
    parser.add_argument("--after", type=int, default=60)
    parser.add_argument("--every", type=int, nargs="*", default=[2, 3])
    parser.add_argument("--early", type=int, default=25)
    parser.add_argument(
        "--drops", type=float, nargs="*", default=[0.1, 0.3],
        help="also: each scan after --before dropped with this probability, on the whole drive",
    )  # fmt: skip
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    methods, _ = methods_and_config([None])
    recordings = {
        "general_tracking_moving_1": load_any(DATA / "general_tracking_moving_1.bag.zip"),
        "simulated_drive": simulate(1000, seed=7, config=SimConfig(scenario="dynamic")),
    }
    tree: dict = {}
    for name, full in recordings.items():
        for every in args.every:
            last = len(full) - every * args.after
            for at in np.linspace(args.before, last, args.places).astype(int):
                recording = slowed(full, int(at), every, args.before, args.after)
                got = scores_from(recording, methods, early_late(args.before, args.early))
                add_counts(tree, f"every_{every}", got)
                add_counts(tree, f"{name}/every_{every}", got)
            print(name, every, flush=True)
        for p in args.drops:
            recording = dropped(full, args.before, p, seed=0)
            got = scores_from(recording, methods, after_drops(recording, args.before))
            add_counts(tree, f"drops_{p:g}", got)
            add_counts(tree, f"{name}/drops_{p:g}", got)
            print(name, p, flush=True)
    out = f1_table(tree)
    for case, by_method in out.items():
        print(case, json.dumps(by_method))
    out["args"] = {k: v for k, v in vars(args).items() if k != "json"}
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
