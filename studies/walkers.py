"""Do the simulator's walkers move like the recordings' people?

Three quantities of the people followed over time, from each source:

- **walking speed** (m/s): the speed of every sample of a track where it moves (at least
  ``STOP_SPEED``);
- **heading change** (rad/s): ``|heading(t + 1) - heading(t)|`` times the frame rate, between
  two consecutive moving samples;
- **stop duration** (s): each run of samples under ``STOP_SPEED`` that follows a moving sample in
  the same track (a stop the track ends in counts up to its end).

Sources: the tracker (:class:`lidarflow.tracking.Tracker`, velocities from its Kalman filter)
on the development recordings of still platforms (positive_1..4,
demo_stationary_simple_environment); the annotated people of general_tracking_moving_1
(``/ground_truth_people_tracks`` by id, put in the odometry frame, velocities by central
differences); and the same tracker on simulated static recordings (the hokuyo-utm sensor of the
positive recordings) with the legacy and with the social walkers, a few seeds each. Per
quantity and simulated source, the two-sample Kolmogorov-Smirnov D (and p-value) against the
pooled tracker samples of the recordings.

    python -m studies.walkers -o runs/walkers [--seeds 3 --frames 900]

Writes OUT/walkers.json (the samples' summaries and the KS statistics) and OUT/walkers.md (the
table the research page holds).
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from lidarflow.tracking import TrackerConfig
from studies.harness import DATA, parse, parser, stem, write_summary

STILL = (
    "positive_1.bag", "positive_2.bag", "positive_3.bag", "positive_4.bag",
    "demo_stationary_simple_environment.bag",
)  # fmt: skip
ANNOTATED = "general_tracking_moving_1.bag.zip"
#: Under this speed (m/s) a person stands.
STOP_SPEED = 0.2
#: Tracks shorter than this (s) or moving less than ``MIN_TRAVEL`` (m) are left out: flicker.
MIN_SECONDS = 1.0
MIN_TRAVEL = 0.3
QUANTITIES = ("speed", "heading_change", "stop_duration")
RES = 0.1
#: The tracker's defaults but a slower background (~10 s), so that someone standing stays a
#: track long enough for a stop to be measured; and 0.5 m from one frame's objects to the next's.
TRACKER = TrackerConfig(alpha=0.01)
LINK = 0.5


def statistics(tracks: list[tuple[np.ndarray, np.ndarray]], rate: float) -> dict[str, list]:
    """The three quantities (module docstring) of ``tracks``: per track ``positions (T, 2)``
    (metres) and ``velocities (T, 2)`` (m/s), one sample per frame at ``rate`` Hz."""
    out: dict[str, list] = {q: [] for q in QUANTITIES}
    for xy, v in tracks:
        if len(xy) < MIN_SECONDS * rate or np.ptp(xy, axis=0).max() < MIN_TRAVEL:
            continue
        speed = np.hypot(v[:, 0], v[:, 1])
        moving = speed >= STOP_SPEED
        out["speed"] += speed[moving].tolist()
        heading = np.arctan2(v[:, 1], v[:, 0])
        both = moving[1:] & moving[:-1]
        turn = np.abs(np.mod(np.diff(heading) + np.pi, 2 * np.pi) - np.pi)
        out["heading_change"] += (turn[both] * rate).tolist()
        run = 0
        for t in range(1, len(speed)):
            if not moving[t] and (moving[t - 1] or run):
                run += 1
            elif run:
                out["stop_duration"].append(run / rate)
                run = 0
        if run:
            out["stop_duration"].append(run / rate)
    return out


def tracked(recording: Any) -> tuple[list[tuple[np.ndarray, np.ndarray]], float]:
    """The tracker's tracks over ``recording`` (a still platform) and its frame rate: each
    frame's objects linked to the last frame's by their predicted positions."""
    from lidarflow.scan import GridSpec
    from lidarflow.tracking import Tracker, associate

    rate = 1e9 / float(np.median(np.diff(recording.stamps_ns)))
    occupancy, visibility = recording.maps(GridSpec())
    tracker = Tracker(TRACKER, res=RES)
    open_: list[tuple[list, list]] = []
    done: list[tuple[list, list]] = []
    last = np.zeros((0, 4))
    for t in range(len(occupancy)):
        tracker.observe(occupancy[t], visibility[t])
        states = np.array([s for s, _ in tracker.tracks().objects]).reshape(-1, 4)
        pairs = associate(last[:, :2] + last[:, 2:], states[:, :2], LINK / RES)
        now: list[tuple[list, list]] = [([], []) for _ in states]
        for i, j in pairs:
            now[j] = open_[i]
        for i in set(range(len(open_))) - {i for i, _ in pairs}:
            done.append(open_[i])
        for (xy, v), s in zip(now, states, strict=True):
            xy.append(s[:2] * RES)
            v.append(s[2:] * RES * rate)
        open_, last = now, states
    done += open_
    return [(np.array(xy), np.array(v)) for xy, v in done], rate


def annotated(path: Path) -> tuple[list[tuple[np.ndarray, np.ndarray]], float]:
    """The annotated people of ``path`` by id, in the odometry frame, with central-difference
    velocities (gaps in a person's frames split the track)."""
    from lidarflow.data import load_any
    from lidarflow.data.bagfile import open_bag
    from lidarflow.evaluate.labels import PEOPLE_TOPIC, frames_by_stamps

    recording = load_any(path)
    period = int(np.median(np.diff(recording.stamps_ns)))
    rows = []
    with open_bag(path) as reader:
        wanted = [c for c in reader.connections if c.topic == PEOPLE_TOPIC]
        for conn, log_time, raw in reader.messages(connections=wanted):
            msg = reader.deserialize(raw, conn.msgtype)
            rows.append((int(log_time), msg.id, msg.pose.position.x, msg.pose.position.y))
    table = np.array(rows, np.float64)
    frames = frames_by_stamps(table[:, 0].astype(np.int64), recording.stamps_ns, period)
    pose = recording.poses[np.maximum(frames, 0)]
    c, s = np.cos(pose[:, 2]), np.sin(pose[:, 2])
    world = np.stack(
        [
            pose[:, 0] + c * table[:, 2] - s * table[:, 3],
            pose[:, 1] + s * table[:, 2] + c * table[:, 3],
        ],
        axis=1,
    )
    rate = 1e9 / period
    tracks = []
    for person in np.unique(table[:, 1]):
        keep = (table[:, 1] == person) & (frames >= 0)
        order = np.argsort(frames[keep])
        f, xy = frames[keep][order], world[keep][order]
        f, first = np.unique(f, return_index=True)
        if len(f) < 3:
            continue
        every = np.arange(f[0], f[-1] + 1)  # the frames a person was left out of, interpolated
        p = np.stack([np.interp(every, f, xy[first, k]) for k in range(2)], axis=1)
        tracks.append((p, np.gradient(p, axis=0) * rate))
    return tracks, rate


def simulated(walkers: str, seed: int, frames: int) -> tuple[list, float]:
    """The tracker's tracks over a static simulated recording with ``walkers``."""
    from dataclasses import replace

    from lidarflow.sim import PeopleConfig, SimConfig, lidar_preset, simulate

    config = SimConfig(
        scenario="static", sensor=lidar_preset("hokuyo-utm"), people=PeopleConfig(),
        episode_frames=frames,
    )  # fmt: skip
    config = replace(config, walkers=walkers)
    return tracked(simulate(frames, seed, config))


def ks(a: Sequence[float], b: Sequence[float]) -> dict[str, float | None]:
    """Two-sample Kolmogorov-Smirnov D and p-value (None where a sample is empty; the p-value
    also where scipy, no dependency of lidarflow, is missing)."""
    if not len(a) or not len(b):
        return {"D": None, "p": None}
    try:
        from scipy.stats import ks_2samp
    except ImportError:
        x, y = np.sort(a), np.sort(b)
        at = np.concatenate([x, y])
        gap = np.searchsorted(x, at, "right") / len(x) - np.searchsorted(y, at, "right") / len(y)
        return {"D": float(np.abs(gap).max()), "p": None}
    result = ks_2samp(a, b)
    return {"D": float(result.statistic), "p": float(result.pvalue)}


def summary(values: Sequence[float]) -> dict[str, float | int | None]:
    if not len(values):
        return {"n": 0, "median": None, "q25": None, "q75": None}
    q25, median, q75 = np.percentile(values, [25, 50, 75])
    return {"n": len(values), "median": float(median), "q25": float(q25), "q75": float(q75)}


def table(sources: dict[str, dict[str, list]], tests: dict[str, dict[str, dict]]) -> str:
    lines = [
        "| source | " + " | ".join(f"{q}: median [IQR] (n)" for q in QUANTITIES) + " |",
        "|---|" + "---|" * len(QUANTITIES),
    ]
    for name, values in sources.items():
        cells = []
        for q in QUANTITIES:
            s = summary(values[q])
            if not s["n"]:
                cells.append("-")
                continue
            cell = f"{s['median']:.2f} [{s['q25']:.2f}, {s['q75']:.2f}] ({s['n']})"
            test = tests.get(name, {}).get(q, {})
            if test.get("D") is not None:
                p = "" if test["p"] is None else f" (p {test['p']:.1g})"
                cell += f", D {test['D']:.2f}{p}"
            cells.append(cell)
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    p = parser("walkers", __doc__)
    p.add_argument("--data", type=Path, default=DATA, help="folder of the recordings")
    p.add_argument("--seeds", type=int, default=3, help="simulated seeds per kind of walker")
    p.add_argument("--frames", type=int, default=900, help="frames per simulated recording")
    p.add_argument("--walkers", nargs="*", default=["legacy", "social"], help="kinds of walkers")
    args = parse(p, argv)
    from lidarflow.data import load_any

    sources: dict[str, dict[str, list]] = {}
    pooled: dict[str, list] = {q: [] for q in QUANTITIES}
    for name in STILL:
        if not (args.data / name).exists():
            continue
        values = statistics(*tracked(load_any(args.data / name)))
        sources[f"tracker: {stem(name)}"] = values
        for q in QUANTITIES:
            pooled[q] += values[q]
    sources["tracker: recordings pooled"] = pooled
    if (args.data / ANNOTATED).exists():
        sources[f"annotated: {stem(ANNOTATED)}"] = statistics(*annotated(args.data / ANNOTATED))
    for walkers in args.walkers:
        values = {q: [] for q in QUANTITIES}
        for seed in range(args.seeds):
            got = statistics(*simulated(walkers, seed, args.frames))
            for q in QUANTITIES:
                values[q] += got[q]
        sources[f"tracker: simulated {walkers}"] = values
    tests = {
        name: {q: ks(values[q], pooled[q]) for q in QUANTITIES}
        for name, values in sources.items()
        if name != "tracker: recordings pooled"
    }
    results = {
        "summary": {n: {q: summary(v[q]) for q in QUANTITIES} for n, v in sources.items()},
        "ks_vs_recordings": tests,
    }
    write_summary(args, "walkers", results, table(sources, tests))
    return results


if __name__ == "__main__":
    try:
        main()
    except KeyboardInterrupt:
        sys.exit(130)
