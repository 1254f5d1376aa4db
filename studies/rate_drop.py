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

    python -m studies.rate_drop -o runs/studies/rate_drop [RECORDING ...]

Writes OUT/rate_drop.json (F1 of all and of the changed cells, per case, method and part;
over all recordings and per recording).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from lidarflow.data.recording import Recording
from lidarflow.motion.pacing import PACE_ABOVE
from studies.harness import parse, parser, stretch_arguments, write_summary
from studies.scoring import (
    add_counts,
    drives,
    early_late,
    f1_table,
    kept_frames,
    methods_for,
    scores_from,
)


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
    """Parts of :func:`studies.scoring.scores_from` for a recording with scans dropped:
    predictions made at a frame after one long step (``after_one``), after two in a row
    (``after_two``), or after a typical step (``after_none``), from ``start`` on. Long: over
    1.5 typical steps."""
    steps = np.diff(np.asarray(recording.stamps_ns, dtype=np.float64))
    long = np.r_[False, steps > PACE_ABOVE * float(np.median(steps))]

    def part(t: int) -> str | None:
        if t < start:
            return None
        return "after_two" if long[t] and long[t - 1] else "after_one" if long[t] else "after_none"

    return part


def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    p = parser("rate_drop", __doc__)
    stretch_arguments(p, "driving recordings", before=60, after=60, early=25)
    p.add_argument("--every", type=int, nargs="*", default=[2, 3], help="the slower rates")
    p.add_argument(
        "--drops",
        type=float,
        nargs="*",
        default=[0.1, 0.3],
        help="also: each scan after --before dropped with this probability, on the whole drive",
    )
    args = parse(p, argv)  # fmt: skip
    methods = methods_for({args.model: args.model})
    tree: dict = {}
    for name, full in drives(args.recordings, 1000).items():
        for every in args.every:
            last = len(full) - every * args.after
            for at in np.linspace(args.before, last, args.places).astype(int):
                recording = slowed(full, int(at), every, args.before, args.after)
                got = scores_from(recording, methods, early_late(args.before, args.early))
                add_counts(tree, f"every_{every}", got)
                add_counts(tree, f"{name}/every_{every}", got)
            print(name, every, flush=True)
        for chance in args.drops:
            recording = dropped(full, args.before, chance, seed=0)
            got = scores_from(recording, methods, after_drops(recording, args.before))
            add_counts(tree, f"drops_{chance:g}", got)
            add_counts(tree, f"{name}/drops_{chance:g}", got)
            print(name, chance, flush=True)
    results = f1_table(tree)
    write_summary(args, "rate_drop", results)
    return results


if __name__ == "__main__":
    main()
