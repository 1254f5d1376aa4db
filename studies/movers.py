"""Issue 44's mover tables: does the default recipe (``head_only``, v9's) beat copy-last, the
temporal average, constant velocity, the ego-moved map and the tracker on what moves, one step
and about one second ahead, on recordings it never saw?

Leave one recording out on the development recordings, each fold trained with every ``--seed``
(``head_only`` from a fresh head, ``model.init=null``, so that no fold starts from weights that
saw its held-out recording; ``--set`` keys go to every run), then each held-out recording scored
with its fold models beside the baselines and the in-sample references (the flow model kept as
a test fixture, v8's recipe, and the bundled v9; both trained on every recording), with
`lidarflow evaluate --horizon K`, K the recording's scans in about one second. On a recording
with annotated people (``/ground_truth_people_tracks``) also the share of people covered at
``t + k`` (:mod:`studies.people`); and the fold models on simulated recordings
(``--sim SCENARIO:SEED``, 15 Hz: K = 15), where the true movers' cells are the region::

    python -m studies.movers -o runs/movers --seeds 0 1 --sim static:11 static:12

Finished trainings and evaluations are kept, so an interrupted study continues; ``--only
train|evaluate|table`` runs one step. Writes OUT/s<seed>/<recording>/run/ per fold,
OUT/evaluation/<recording>.json per held-out recording (with ``people`` where annotated),
OUT/sim/<name>.json, and OUT/movers.{md,json} and OUT/summary.json (the tables,
:mod:`studies.mover_tables`): per fold and aggregated, each method's F1, exact and tolerant
mover F1 at k = 1 and K, and the verdicts against issue 44's targets.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from studies.harness import development, parse, parser, read_json, stem, write_json
from studies.mover_tables import KEYS, REFERENCES, collect, write_tables

RECIPE = "head_only"
#: every fold starts from a fresh head: the bundled head, the recipe's default, saw every recording
FOLD_SETTINGS = ("model.init=null", "runtime.tensorboard=false")
PEOPLE_TOPIC = "/ground_truth_people_tracks"
#: the people-share methods
PEOPLE_METHODS = ("copy_last", "tracker")
#: a recording whose platform moved more than this (metres, poses' extent) is a moving one
MOVED = 0.5
SIM_FRAMES = 300


def fold_run(out: Path, seed: int, held: Path | str) -> Path:
    return out / f"s{seed}" / stem(held) / "run"


def train_folds(
    out: Path, recordings: Sequence[Path], held: Sequence[Path], seeds: Sequence[int], sets: list
) -> None:
    """Every fold of ``held``, seed by seed (all folds of the first seed first)."""
    from studies.folds import train_model

    for seed in seeds:
        for h in held:
            others = [r for r in recordings if r != h]
            overrides = [*FOLD_SETTINGS, f"runtime.seed={seed}", *sets]
            train_model(others, fold_run(out, seed, h), RECIPE, overrides)


def horizon_of(recording: Any) -> int:
    """The scans in about one second (8 at 7.5 Hz, 10 at 10 Hz, 13 at ~13 Hz, 15 at 15 Hz)."""
    return max(2, round(recording.frame_rate))


def moved(recording: Any) -> bool:
    poses = recording.poses
    if poses is None or not np.isfinite(poses[:, :2]).any():
        return False
    return bool(np.nanmax(np.ptp(poses[:, :2][np.isfinite(poses[:, 0])], axis=0)) > MOVED)


def read_people(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """``(stamps_ns, xy)`` of the annotated people of a bag: the bag's log stamps (the messages
    have no header) and the positions as recorded (laser frame); empty without the topic or
    where ``path`` is no bag."""
    from lidarflow.data.bagfile import open_bag

    stamps: list[int] = []
    xy: list[tuple[float, float]] = []
    if not path.name.endswith((".bag", ".bag.zip")):
        return np.zeros(0, np.int64), np.zeros((0, 2))
    with open_bag(path) as reader:
        # AnyReader registers leg_tracker/msg/Person from the bag's own message definition
        connections = [c for c in reader.connections if c.topic == PEOPLE_TOPIC]
        # no connections given, rosbags reads every message: none asked, none read
        for con, stamp, raw in reader.messages(connections=connections) if connections else ():
            p = reader.deserialize(raw, con.msgtype).pose.position
            stamps.append(stamp)
            xy.append((p.x, p.y))
    return np.array(stamps, np.int64), np.array(xy, np.float64).reshape(-1, 2)


def people_by_frame(path: Path, recording: Any, lag_scans: float) -> dict[int, np.ndarray]:
    """The annotated people per frame, each annotation given to the scan nearest its stamp
    less ``lag_scans`` scan periods."""
    from studies.people import frames_of

    stamps, xy = read_people(path)
    if not len(stamps):
        return {}
    period = float(np.median(np.diff(recording.stamps_ns)))
    frames = frames_of(stamps, recording.stamps_ns, round(lag_scans * period))
    return {int(f): xy[frames == f] for f in np.unique(frames)}


def stamp_check(path: Path, recording: Any, grid: Any) -> dict[str, float | None]:
    """The share of annotated people within the radius of an occupied cell of the scan they are
    given to, for lags of -1 .. 2 scan periods: how the annotations' stamp was placed."""
    from studies.people import PeopleCounts, people_found

    occupancy, _ = recording.maps(grid)
    out = {}
    for lag in (-1, 0, 1, 2):
        total = PeopleCounts()
        for f, xy in people_by_frame(path, recording, lag).items():
            total = total + people_found(occupancy[f] >= 0.5, xy, grid)
        out[f"lag_{lag}"] = total.share
    return out


def grid_of(run: str | Path) -> Any:
    """The grid a fold model trained on (its ``model.json``)."""
    from lidarflow.scan import GridSpec

    grid = read_json(Path(run) / "model.json")["grid"]
    return GridSpec(grid["height"], grid["width"], grid["res"])


def evaluate_held(
    out: Path, held: Path, seeds: Sequence[int], references: Sequence[str], horizon: int = 0
) -> Path | None:
    """Score ``held`` with its fold models (and the references), ``horizon`` steps ahead (0:
    about one second): OUT/evaluation/<held>.json. Kept where it exists with every fold model
    now trained; ``None`` where no fold model is."""
    from lidarflow.data import load_any
    from lidarflow.evaluate.metrics import THRESHOLD
    from studies.people import PeopleCounts, people_found
    from studies.scoring import evaluate

    path = out / "evaluation" / f"{stem(held)}.json"
    models = {
        f"s{s}": str(fold_run(out, s, held))
        for s in seeds
        if (fold_run(out, s, held) / "model.safetensors").exists()
    }
    if not models:
        return None
    if path.exists() and set(models) <= set(read_json(path)["fold_models"]):
        return path
    grid = grid_of(next(iter(models.values())))
    models.update({name: REFERENCES[name] for name in references})
    recording = load_any(held)
    k = horizon or horizon_of(recording)
    people = people_by_frame(held, recording, 1.0)
    counts: dict[str, list[PeopleCounts]] = {}

    def on_ahead(_name: str, method: str, t: int, predicted: np.ndarray) -> None:
        if method not in (*PEOPLE_METHODS, *(m for m in models if m.startswith("s"))):
            return
        mine = counts.setdefault(method, [PeopleCounts() for _ in range(k)])
        for step in range(k):
            if (xy := people.get(t + 1 + step)) is not None:
                mine[step] = mine[step] + people_found(predicted[step] >= THRESHOLD, xy, grid)

    report = evaluate(
        [(str(held), recording)],
        models,
        grid=grid,
        horizon=k,
        on_ahead=on_ahead if people else None,
    )
    entry = report["recordings"][0]
    result: dict[str, Any] = {
        "recording": stem(held),
        "K": k,
        "moving": moved(recording),
        "fold_models": sorted(m for m in models if m not in REFERENCES),
        "references": sorted(m for m in models if m in REFERENCES),
        "scores": rows_of(entry),
        "frames_scored": entry.get("frames"),
    }
    if people:
        result["people"] = {
            m: {"share": [c.share for c in per_k], "counted": [c.counted for c in per_k]}
            for m, per_k in counts.items()
        }
        result["people_stamp_check"] = stamp_check(held, recording, grid)
    write_json(path, result)
    return path


def rows_of(entry: dict[str, Any]) -> dict[str, dict[str, list[float]]]:
    """``{method: {f1: [k = 1..K], mover_f1: [...], mover_f1_tolerant: [...]}}`` of a report's
    recording entry (the horizon scores: every k over the same frames)."""
    return {
        method: {key: entry[f"horizon_{key}"][method] for key in KEYS}
        for method in entry["horizon_f1"]
    }


def evaluate_sim(
    out: Path, spec: str, models: dict[str, str], frames: int = SIM_FRAMES, horizon: int = 0
) -> Path:
    """Score ``models`` on the simulated recording ``SCENARIO:SEED`` of ``frames`` frames,
    ``horizon`` ahead (0: the scans in ~1 s): OUT/sim/<scenario>_<seed>.json; kept where it
    holds every model."""
    from lidarflow.sim import SimConfig, simulate
    from studies.scoring import evaluate

    scenario, _, seed = spec.partition(":")
    path = out / "sim" / f"{scenario}_{seed}.json"
    if path.exists() and set(models) <= set(read_json(path)["models"]):
        return path
    grid = grid_of(next(iter(models.values())))
    config = SimConfig(scenario=scenario, grid=grid)
    recording = simulate(frames, seed=int(seed), config=config)
    k = horizon or horizon_of(recording)
    entry = evaluate([(spec, recording)], models, grid=grid, horizon=k)["recordings"][0]
    write_json(
        path, {"recording": spec, "K": k, "models": sorted(models), "scores": rows_of(entry)}
    )
    return path


def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    p = parser("movers", __doc__)
    p.add_argument("--recordings", type=Path, nargs="+", default=development())
    p.add_argument("--held-out", type=Path, nargs="*", default=[], help="only these folds")
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1], help="training seeds")
    p.add_argument("--set", dest="sets", nargs="*", default=[], help="KEY=VALUE for every run")
    p.add_argument(
        "--references",
        nargs="*",
        choices=tuple(REFERENCES),
        default=list(REFERENCES),
        help="the in-sample references scored beside the fold models (default: both; none: "
        "give the flag alone)",
    )
    p.add_argument("--sim", nargs="*", default=[], help="SCENARIO:SEED simulated recordings")
    p.add_argument("--sim-frames", type=int, default=SIM_FRAMES, help="frames per simulation")
    p.add_argument("--horizon", type=int, default=0, help="K (0: the scans in about 1 s)")
    p.add_argument("--only", choices=("train", "evaluate", "table"), help="one step only")
    args = parse(p, argv)
    if unknown := [str(r) for r in args.held_out if r not in args.recordings]:
        p.error(f"--held-out must be among --recordings: {', '.join(unknown)}")
    out: Path = args.output
    held = args.held_out or args.recordings
    if args.only in (None, "train"):
        train_folds(out, args.recordings, held, args.seeds, args.sets)
    if args.only in (None, "evaluate"):
        for h in held:
            done = evaluate_held(out, h, args.seeds, args.references, args.horizon)
            print(f"{stem(h)}: {done or 'no fold model yet'}", flush=True)
        fold_models = {
            f"{stem(h)}_s{s}": str(fold_run(out, s, h))
            for s in args.seeds
            for h in args.recordings
            if (fold_run(out, s, h) / "model.safetensors").exists()
        }
        for spec in args.sim if fold_models else []:
            done = evaluate_sim(out, spec, fold_models, args.sim_frames, args.horizon)
            print(f"{spec}: {done}", flush=True)
    study = collect(out)
    write_tables(out, args.command, study, args)
    return study


if __name__ == "__main__":
    main()
