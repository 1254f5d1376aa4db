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

    python experiments/pose_jumps.py --json docs/results/gaps/pose_jumps.json
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import numpy as np
from study import add_counts, early_late, f1_table, scores_from

from lidarflow.cli.scoring import methods_and_config
from lidarflow.data import load_any
from lidarflow.sim import SimConfig, simulate
from lidarflow.sim.platform import compose, relative

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def jumped(poses: np.ndarray, at: int, jump: tuple[float, float, float] | None) -> np.ndarray:
    """``poses`` with every pose from ``at`` on seen from another fixed frame: the frame in
    which pose ``at`` is ``(0, 0, 0)`` (``jump=None``, an odometry reset), or moved by ``jump``
    ``(x, y, yaw)`` (a relocalisation)."""
    out = np.asarray(poses, dtype=np.float64).copy()
    origin = out[at].copy()
    for t in range(at, len(out)):
        out[t] = relative(origin, out[t]) if jump is None else compose(np.asarray(jump), out[t])
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "recordings", nargs="*", type=Path,
        help="recordings with poses (default: general_tracking_moving_1 and a simulated drive)",
    )  # fmt: skip
    parser.add_argument("--places", type=int, default=4)
    parser.add_argument("--before", type=int, default=40)
    parser.add_argument("--after", type=int, default=30)
    parser.add_argument("--early", type=int, default=5)
    parser.add_argument("--shift", type=float, nargs=2, default=[2.0, -1.0])
    parser.add_argument("--turn", type=float, default=30.0)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    methods, _ = methods_and_config([None])
    if args.recordings:
        loaded = {p.name: load_any(p) for p in args.recordings}
    else:
        sim = simulate(600, seed=7, config=SimConfig(scenario="dynamic"))
        loaded = {
            "general_tracking_moving_1": load_any(DATA / "general_tracking_moving_1.bag.zip"),
            "simulated_drive": sim,
        }
    relocalise = (args.shift[0], args.shift[1], float(np.deg2rad(args.turn)))
    tree: dict = {}
    for name, recording in loaded.items():
        if not recording.has_poses:
            raise SystemExit(f"{name} has no poses: a pose jump needs them")
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
    out = f1_table(tree)
    out["args"] = {k: v for k, v in vars(args).items() if k not in ("json", "recordings")}
    for case, by_method in out.items():
        print(case, json.dumps(by_method))
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(out, indent=1, default=str))


if __name__ == "__main__":
    main()
