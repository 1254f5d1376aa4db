"""Odometry that jumps mid-stream (a reset to zero, a relocalisation): what it costs.

A robot's pose source can jump: odometry reset to the origin when a driver restarts, a
localiser snapping to a new estimate. From the jump on the poses are those of the same motion in
another fixed frame, so one step's motion (the one across the jump) is wrong by the jump, and an
ego-motion model both compensates that step by it and guesses the next motion from it.

This takes a recording with poses (or simulates a driving one), keeps ``--before`` frames before
each of ``--places`` frames and ``--after`` after, moves every pose from that frame on by a
rigid jump (``reset``: the pose there becomes ``(0, 0, 0)``; ``relocalise``: ``--shift`` metres
and ``--turn`` degrees), streams the bundled model and the baselines over it and over the same
frames without the jump, and scores the first ``--early`` predictions made from the jump's frame
on and the rest (F1 / changed-cell F1).

    python -m studies.pose_jumps -o runs/studies/pose_jumps [RECORDING ...]

Writes OUT/pose_jumps.json (F1 of all and of the changed cells, per case, method and part;
over all recordings and per recording).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np

from lidarflow.sim.platform import compose, relative
from studies.harness import parse, parser, stretch_arguments, write_summary
from studies.scoring import add_counts, drives, early_late, f1_table, methods_for, scores_from


def jumped(poses: np.ndarray, at: int, jump: tuple[float, float, float] | None) -> np.ndarray:
    """``poses`` with every pose from ``at`` on seen from another fixed frame: the frame in
    which pose ``at`` is ``(0, 0, 0)`` (``jump=None``, an odometry reset), or moved by ``jump``
    ``(x, y, yaw)`` (a relocalisation)."""
    out = np.asarray(poses, dtype=np.float64).copy()
    origin = out[at].copy()
    for t in range(at, len(out)):
        out[t] = relative(origin, out[t]) if jump is None else compose(np.asarray(jump), out[t])
    return out


def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    p = parser("pose_jumps", __doc__)
    stretch_arguments(p, "recordings with poses", before=40, after=30, early=5)
    p.add_argument("--shift", type=float, nargs=2, default=[2.0, -1.0])
    p.add_argument("--turn", type=float, default=30.0)
    args = parse(p, argv)  # fmt: skip
    methods = methods_for({args.model: args.model})
    loaded = drives(args.recordings, 600)
    relocalise = (args.shift[0], args.shift[1], float(np.deg2rad(args.turn)))
    tree: dict = {}
    for name, recording in loaded.items():
        if not recording.has_poses:
            p.error(f"{name} has no poses: a pose jump needs them")
        last = len(recording) - args.after - 1
        for at in np.linspace(args.before, last, args.places).astype(int):
            cut = recording.slice(int(at) - args.before, int(at) + args.after + 1)
            for case, jump in (("none", False), ("reset", None), ("relocalise", relocalise)):
                poses = cut.poses if jump is False else jumped(cut.poses, args.before, jump)
                moved = dataclasses.replace(cut, poses=poses)
                got = scores_from(moved, methods, early_late(args.before, args.early))
                add_counts(tree, case, got)
                add_counts(tree, f"{name}/{case}", got)
            print(name, int(at), flush=True)
    results = f1_table(tree)
    write_summary(args, "pose_jumps", results)
    return results


if __name__ == "__main__":
    main()
