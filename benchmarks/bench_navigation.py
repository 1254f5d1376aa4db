"""Closed loop: does a robot that plans on lidarflow's predicted maps get through people better?

The same sampling local planner (:mod:`lidarflow.sim.local_planner`) drives a 0.3 m
differential-drive robot across an open 12 x 12 m hall to a goal 6-10 m away through social
walkers (:mod:`lidarflow.sim.navigation`), with its obstacles from each of four sources
(:mod:`lidarflow.sim.obstacles`): ``last_scan``, ``lidarflow`` (the bundled model's maps 1 s
ahead), ``tracker`` and ``true_future`` (the ceiling); on request ``lidarflow_default`` (the
Predictor's default: the model's first frame, the online combination's frames after it) and
``lidarflow_combined`` (the combination on every frame), each learning from its episode's scans.
Episode ``seed`` of a crowd size is the same scene for every source. Per source and crowd size:
success rate and collision rate (95 % Wilson intervals), the smallest robot-person centre
distance (mean over episodes with people) and the time to goal (mean over successes), both with
95 % bootstrap intervals of the mean. Beside the last scan, each other source's collisions are
compared episode by episode on the same scenes (``vs_last_scan``: the scenes where only the last
scan collided, where only the source did, and the exact two-sided sign test's p-value on those).

    python benchmarks/bench_navigation.py                  # small: crowds 0 4 8, 10 episodes
    python benchmarks/bench_navigation.py --episodes 100 --crowds 0 2 4 6 8 10 12   # the full one

The small one takes ~5 minutes on 2 cores; the full one about 25 times that (``--workers``
spreads episodes over processes; ``--log FILE`` keeps every finished episode, one JSON line
each, and a rerun with the same log skips them, so a long run can stop and resume; ``--from-log``
reports what a log holds without running anything). Writes JSON
keyed by source, then crowd size (default ``benchmarks/results/navigation.json``), and a plot
beside it (``.png``) where matplotlib is installed.
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing
import time
from pathlib import Path
from typing import Any

import numpy as np
from _output import machine, write_json

from lidarflow.predict import Predictor
from lidarflow.sim.navigation import NavConfig, Outcome, run_episode
from lidarflow.sim.obstacles import SOURCES, make_source

RESULTS = Path(__file__).resolve().parent / "results"
#: The sources a Predictor makes, by its ``combine``: the bundled model alone (as its results
#: were first made), the default (the online combination from frame 2 on) and the combination
#: on every frame; each reset with every episode.
PREDICTED = {"lidarflow": False, "lidarflow_default": None, "lidarflow_combined": True}
CHOICES = (*SOURCES, "lidarflow_default", "lidarflow_combined")
# one per process and (grid, horizon, combine), reset every episode
_PREDICTORS: dict[tuple[Any, int, bool | None], Predictor] = {}


def wilson(successes: int, n: int, z: float = 1.96) -> list[float] | None:
    """The 95 % Wilson score interval of a rate ``successes / n`` (``None`` for ``n = 0``)."""
    if n == 0:
        return None
    p = successes / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    # At p = 0 or 1 the bound equals p in exact arithmetic; rounding must not leave p outside.
    return [min(p, max(0.0, centre - half)), max(p, min(1.0, centre + half))]


def bootstrap(values: list[float], rounds: int = 2000) -> list[float] | None:
    """The 95 % percentile bootstrap interval of the mean of ``values`` (seeded)."""
    if not values:
        return None
    x = np.asarray(values, np.float64)
    means = x[np.random.default_rng(0).integers(0, len(x), (rounds, len(x)))].mean(1)
    return [float(np.percentile(means, 2.5)), float(np.percentile(means, 97.5))]


def paired(base: dict[int, Outcome], other: dict[int, Outcome]) -> dict[str, Any]:
    """Collisions on the same scenes (by seed): where only ``base`` collided (``fewer``),
    where only ``other`` did (``more``), and the exact two-sided sign test's ``p``."""
    seeds = base.keys() & other.keys()
    fewer = sum(base[s].collision and not other[s].collision for s in seeds)
    more = sum(other[s].collision and not base[s].collision for s in seeds)
    n = fewer + more
    tail = sum(math.comb(n, i) for i in range(min(fewer, more) + 1)) / 2**n if n else 1.0
    return {"fewer_collisions": fewer, "more_collisions": more, "p": min(1.0, 2 * tail)}


def episode(job: tuple[str, int, int]) -> tuple[str, int, int, Outcome]:
    """Run one ``(source, crowd size, seed)``."""
    name, walkers, seed = job
    config = NavConfig(walkers=walkers)
    predictor = None
    if name in PREDICTED:
        combine = PREDICTED[name]
        key = (config.grid, config.horizon, combine)
        if key not in _PREDICTORS:
            _PREDICTORS[key] = Predictor(grid=config.grid, horizon=config.horizon, combine=combine)
        predictor = _PREDICTORS[key]
    source = make_source(
        "lidarflow" if name in PREDICTED else name, config.grid, config.horizon, predictor
    )
    return name, walkers, seed, run_episode(source, seed, config)


def read_log(path: Path | None) -> dict[tuple[str, int, int], Outcome]:
    """The episodes a previous run finished, by ``(source, crowd size, seed)``; a torn last
    line (the run killed while writing it) is skipped."""
    if path is None or not path.exists():
        return {}
    done = {}
    for line in path.read_text().splitlines():
        try:
            row = json.loads(line)
        except json.JSONDecodeError:
            continue
        outcome = Outcome(row["success"], row["collision"], row["time_s"],
                          row["min_distance_m"], np.zeros((0, 3)))  # fmt: skip
        done[(row["source"], row["walkers"], row["seed"])] = outcome
    return done


def log_line(name: str, walkers: int, seed: int, outcome: Outcome) -> str:
    """One finished episode as a JSON line (the path is not kept)."""
    row = {"source": name, "walkers": walkers, "seed": seed, "success": outcome.success,
           "collision": outcome.collision, "time_s": outcome.time_s,
           "min_distance_m": outcome.min_distance_m}  # fmt: skip
    return json.dumps(row) + "\n"


def summary(outcomes: list[Outcome]) -> dict[str, Any]:
    """One source and crowd size's rates and means with their intervals."""
    n = len(outcomes)
    wins = sum(o.success for o in outcomes)
    hits = sum(o.collision for o in outcomes)
    near = [o.min_distance_m for o in outcomes if not math.isnan(o.min_distance_m)]
    times = [o.time_s for o in outcomes if o.success]
    return {
        "episodes": n,
        "success_rate": wins / n if n else None,
        "success_rate_ci": wilson(wins, n),
        "collision_rate": hits / n if n else None,
        "collision_rate_ci": wilson(hits, n),
        "timeout_rate": (n - wins - hits) / n if n else None,
        "min_distance_m": float(np.mean(near)) if near else None,
        "min_distance_m_ci": bootstrap(near),
        "time_s": float(np.mean(times)) if times else None,
        "time_s_ci": bootstrap(times),
    }


def plot(result: dict[str, Any], crowds: list[int], path: Path) -> None:
    """Four panels against the crowd size, one line per source with its 95 % intervals."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("matplotlib is not installed: no plot")
        return
    panels = [
        ("success_rate", "success rate"),
        ("collision_rate", "collision rate"),
        ("min_distance_m", "min distance to a person (m)"),
        ("time_s", "time to goal (s)"),
    ]
    fig, axes = plt.subplots(1, 4, figsize=(16, 3.8))
    for ax, (key, label) in zip(axes, panels, strict=True):
        for i, name in enumerate(SOURCES):
            rows = [result[name][str(c)] for c in crowds]
            xs = [
                c + 0.12 * (i - 1.5)
                for c, r in zip(crowds, rows, strict=True)
                if r[key] is not None
            ]
            ys = [r[key] for r in rows if r[key] is not None]
            err = np.array([[r[key] - r[f"{key}_ci"][0], r[f"{key}_ci"][1] - r[key]]
                            for r in rows if r[key] is not None]).T.reshape(2, -1)  # fmt: skip
            ax.errorbar(xs, ys, yerr=err, marker="o", capsize=3, label=name)
        ax.set_xlabel("walkers")
        ax.set_title(label)
    axes[0].legend()
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    print(f"wrote {path}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=10, help="seeded episodes per cell")
    parser.add_argument("--crowds", type=int, nargs="+", default=[0, 4, 8], help="walkers")
    parser.add_argument(
        "--sources", nargs="+", default=list(SOURCES), choices=CHOICES,
        help=f"of {', '.join(CHOICES)} (default: the first four)",
    )  # fmt: skip
    parser.add_argument("--workers", type=int, default=1, help="processes")
    parser.add_argument("--json", type=Path, default=RESULTS / "navigation.json")
    parser.add_argument("--log", type=Path, help="JSON lines of finished episodes (resumable)")
    parser.add_argument(
        "--from-log", action="store_true",
        help="run nothing: report the episodes the log holds (a run stopped part way)",
    )  # fmt: skip
    args = parser.parse_args()
    if args.from_log and args.log is None:
        parser.error("--from-log needs --log")
    jobs = [(s, c, e) for c in args.crowds for e in range(args.episodes) for s in args.sources]
    logged = read_log(args.log)
    todo = [] if args.from_log else [job for job in jobs if job not in logged]
    if logged:
        print(f"{len(jobs) - len(todo)} of {len(jobs)} episodes already in {args.log}")
    start = time.perf_counter()
    outcomes = [(*job, logged[job]) for job in jobs if job in logged]
    log = None
    if args.log and not args.from_log:
        torn = args.log.exists() and not args.log.read_bytes().endswith(b"\n")
        log = args.log.open("a")
        log.write("\n" if torn and args.log.stat().st_size else "")
    pool = multiprocessing.get_context("fork").Pool(args.workers) if args.workers > 1 else _Serial()
    with pool:
        for finished in pool.imap_unordered(episode, todo):
            outcomes.append(finished)
            if log:
                log.write(log_line(*finished))
                log.flush()
    if log:
        log.close()
    done: dict[tuple[str, int], dict[int, Outcome]] = {}
    for name, walkers, seed, outcome in outcomes:
        done.setdefault((name, walkers), {})[seed] = outcome
    elapsed = time.perf_counter() - start
    result: dict[str, Any] = {
        name: {str(c): summary(list(done.get((name, c), {}).values())) for c in args.crowds}
        for name in args.sources
    }
    if "last_scan" in args.sources:
        for name in args.sources:
            for c in args.crowds:
                if name != "last_scan":
                    base, other = done.get(("last_scan", c), {}), done.get((name, c), {})
                    result[name][str(c)]["vs_last_scan"] = paired(base, other)
    config = NavConfig()
    result["setup"] = {
        "episodes": args.episodes,
        "crowds": args.crowds,
        "hall_m": list(config.hall),
        "goal_distance_m": list(config.goal_distance),
        "horizon_frames": config.horizon,
        "sensor": config.sensor.name,
        "max_time_s": config.max_time,
        "walkers": "social",
        # A report from the log ran nothing: how the episodes were run is not known here.
        "workers": None if args.from_log else args.workers,
        "elapsed_s": None if args.from_log else round(elapsed, 1),
        "from_log": args.from_log,
        "machine": machine(),
    }
    write_json(args.json, result)
    print(f"{'source':12s} {'crowd':>5s} {'success':>16s} {'collision':>16s} "
          f"{'min dist m':>18s} {'time s':>18s}")  # fmt: skip
    for name in args.sources:
        for c in args.crowds:
            print(f"{name:12s} {c:5d} " + " ".join(_cell(result[name][str(c)], k) for k in (
                "success_rate", "collision_rate", "min_distance_m", "time_s")))  # fmt: skip
    for name in args.sources:
        for c in args.crowds:
            if "vs_last_scan" in result[name][str(c)]:
                v = result[name][str(c)]["vs_last_scan"]
                print(f"{name:12s} {c:5d} vs last_scan: collides where it does not on "
                      f"{v['more_collisions']} scenes, avoids where it collides on "
                      f"{v['fewer_collisions']}; sign test p = {v['p']:.3f}")
    print(f"{len(jobs)} episodes in {elapsed:.0f} s")
    if set(args.sources) == set(SOURCES):
        plot(result, args.crowds, args.json.with_suffix(".png"))


class _Serial:
    """A pool of one: the episodes in this process, in order."""

    def __enter__(self) -> _Serial:
        return self

    def __exit__(self, *exc: object) -> None:
        return None

    def imap_unordered(self, fn: Any, jobs: list[Any]) -> Any:
        return map(fn, jobs)


def _cell(row: dict[str, Any], key: str) -> str:
    if row[key] is None:
        return f"{'-':>18s}"
    lo, hi = row[f"{key}_ci"]
    return f"{row[key]:6.2f} [{lo:4.2f},{hi:5.2f}]"


if __name__ == "__main__":
    main()
