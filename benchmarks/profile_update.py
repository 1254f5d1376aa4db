"""Where the time of ``Predictor.update`` goes, per path: cProfile at 1 thread, shares of the
update by stage (issue 46's closing note; docs/research/step_speed/).

Paths: ``fixed`` (poses given, the decision at its fixed offset), ``online`` (poses, online
decision), ``h8`` (poses, online, ``horizon=8``), ``noposes`` (motion matched from the scans,
online). Poses are a slow drive's, as ``bench_step.py`` gives them (odometry check off); the
recording is the bundled sample (``positive_2``) or one under ``../shared/data``. Run it with
``OMP_NUM_THREADS=1``; prints one markdown table per path.

    python benchmarks/profile_update.py fixed@sample online@sample h8@sample noposes@sample
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
from pathlib import Path
from typing import Any

import torch
from bench_predict import drive

from lidarflow import compiled
from lidarflow.data import load_any, read_bag, sample_bag_path
from lidarflow.predict import Predictor

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
PATHS = {  # online decision, horizon, poses given
    "fixed": (False, 1, True),
    "online": (True, 1, True),
    "h8": (True, 8, True),
    "noposes": (True, 1, False),
}


def _cumulative(stats: dict[Any, Any], name: str, caller: str | None = None) -> float:
    """Seconds spent in functions whose ``file:function`` ends with ``name`` (called from
    ``caller`` only, where given)."""
    total = 0.0
    for (path, _, function), (_, _, _, cumulative, callers) in stats.items():
        if not f"{path}:{function}".endswith(name):
            continue
        if caller is None:
            total += cumulative
        else:
            total += sum(
                v[3] for (cp, _, cf), v in callers.items() if f"{cp}:{cf}".endswith(caller)
            )
    return total


def profile(path: str, recording: str, frames: int = 150) -> None:
    scans = list(
        read_bag(sample_bag_path()) if recording == "sample" else load_any(SHARED / recording)
    )[:frames]
    n = len(scans)
    poses = drive(frames)
    online, horizon, with_poses = PATHS[path]
    options: dict[str, Any] = {"threads": 1, "online_decision": online, "horizon": horizon}
    if with_poses:
        options["check_odometry"] = False
    predictor = Predictor(None, **options)

    def update(j: int) -> None:
        predictor.update(scans[j % n], poses[j] if with_poses else None)

    for j in range(10):  # warm up
        update(j)
    compiled.wait()  # the kernels compile in the background: all of them, before the profile
    profiler = cProfile.Profile()
    profiler.enable()
    for j in range(10, frames):
        update(j)
    profiler.disable()
    stats = pstats.Stats(profiler).stats  # type: ignore[attr-defined]

    def ct(name: str, caller: str | None = None) -> float:
        return _cumulative(stats, name, caller)

    total = ct("predictor.py:update")
    rows = {
        "scan matching (ScanOdometry)": ct("engine.py:_motion"),
        "model step (head step)": ct("headstep.py:run", "engine.py:step"),
        "decision (online: score, choose, decide)": ct("engine.py:_decide", "engine.py:step"),
        "tracker (observe)": ct("tracker.py:observe"),
        "tracks one step on (Tracks.at)": ct("tracks.py:at", "engine.py:step"),
        "roll-out: model steps": ct("headstep.py:run", "engine.py:roll"),
        "roll-out: re-decision": ct("engine.py:_decide", "engine.py:roll"),
        "roll-out: tracks k steps on": ct("tracks.py:at", "engine.py:roll"),
        "rasterise + sub-cell maps": ct("predictor.py:_maps") + ct("scan.py:subcell_batch"),
        "returns (scan_points)": ct("icp.py:scan_points", "predictor.py:update"),
    }
    rolled = sum(v for k, v in rows.items() if k.startswith("roll-out"))
    rows["roll-out: the rest (stacking)"] = ct("engine.py:roll") - rolled
    rows["the rest (Frame, Prediction, pacing, input stack)"] = total - sum(rows.values())
    print(f"\n{path} on {recording}: {1e3 * total / (frames - 10):.2f} ms a scan profiled")
    print("| stage | share |\n|---|---|")
    for name, seconds in rows.items():
        if seconds > 0.005 * total:
            print(f"| {name} | {100 * seconds / total:.0f} % |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "paths",
        nargs="*",
        default=["fixed@sample", "online@sample", "h8@sample", "noposes@sample"],
        help=f"PATH@RECORDING, PATH one of {', '.join(PATHS)} (default: all four on the sample)",
    )
    parser.add_argument("--frames", type=int, default=150, help="scans per path (10 warm up)")
    args = parser.parse_args()
    specs = [spec.partition("@") for spec in args.paths]
    unknown = [path for path, _, _ in specs if path not in PATHS]
    if unknown:
        parser.error(f"unknown path {unknown[0]!r}: choose from {', '.join(PATHS)}")
    missing = [r for _, _, r in specs if r and r != "sample" and not (SHARED / r).exists()]
    if missing:
        parser.error(f"no recording {missing[0]!r} under {SHARED}")
    if args.frames <= 10:
        parser.error("--frames must be above 10 (the first 10 warm up)")
    torch.set_num_threads(1)
    for path, _, recording in specs:
        profile(path, recording or "sample", args.frames)


if __name__ == "__main__":
    main()
