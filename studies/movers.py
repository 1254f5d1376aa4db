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
``t + k`` (:mod:`lidarflow.evaluate.people`); and the fold models on simulated recordings
(``--sim SCENARIO:SEED``, 15 Hz: K = 15), where the true movers' cells are the region::

    python -m studies.movers -o runs/movers --seeds 0 1 --sim static:11 static:12

Finished trainings and evaluations are kept, so an interrupted study continues; ``--only
train|evaluate|table`` runs one step. Writes OUT/s<seed>/<recording>/run/ per fold,
OUT/evaluation/<recording>.json per held-out recording (with ``people`` where annotated),
OUT/sim/<name>.json, and OUT/movers.{md,json}: per fold and aggregated, each method's F1, exact
and tolerant mover F1 at k = 1 and K, and the verdicts against issue 44's targets.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from studies.harness import (
    BASELINES,
    development,
    parse,
    parser,
    read_json,
    stem,
    write_json,
    write_summary,
)

RECIPE = "head_only"
#: every fold starts from a fresh head: the bundled head, the recipe's default, saw every recording
FOLD_SETTINGS = ("model.init=null", "runtime.tensorboard=false")
#: scored beside the fold models, in-sample (trained on every development recording)
REFERENCES = {"flownet_v8": "tests/fixtures/flownet_v8", "bundled_v9": "bundled"}
EGO = "copy_last_ego"
PEOPLE_TOPIC = "/ground_truth_people_tracks"
#: the people-share methods
PEOPLE_METHODS = ("copy_last", "tracker")
#: a recording whose platform moved more than this (metres, poses' extent) is a moving one
MOVED = 0.5
SIM_FRAMES = 300
KEYS = ("f1", "mover_f1", "mover_f1_tolerant")


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
    from lidarflow.data.bags import open_bag

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
    from lidarflow.evaluate.people import frames_of

    stamps, xy = read_people(path)
    if not len(stamps):
        return {}
    period = float(np.median(np.diff(recording.stamps_ns)))
    frames = frames_of(stamps, recording.stamps_ns, round(lag_scans * period))
    return {int(f): xy[frames == f] for f in np.unique(frames)}


def stamp_check(path: Path, recording: Any, grid: Any) -> dict[str, float | None]:
    """The share of annotated people within the radius of an occupied cell of the scan they are
    given to, for lags of -1 .. 2 scan periods: how the annotations' stamp was placed."""
    from lidarflow.evaluate.people import PeopleCounts, people_found

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
    from lidarflow.evaluate.people import PeopleCounts, people_found
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


# ---- the tables ------------------------------------------------------------------------------


def at(row: dict[str, list[float]], key: str, k: str) -> float:
    values = row[key]
    return float(values[0] if k == "1" else values[-1])


def model_stats(scores: dict, seeds: Sequence[str], key: str, k: str) -> tuple[float, float]:
    """Mean and half-spread (half of max - min) of the fold models' ``key`` at ``k``."""
    values = [at(scores[s], key, k) for s in seeds]
    return float(np.mean(values)), (max(values) - min(values)) / 2


def baselines_of(fold: dict) -> list[str]:
    """The baselines a fold is judged against: the four, and the ego-moved map where the
    platform moved."""
    return [b for b in (*BASELINES, *([EGO] if fold["moving"] else [])) if b in fold["scores"]]


def targets(fold: dict) -> dict[str, dict[str, Any]]:
    """Issue 44's targets for one held-out recording: each ``{"model", "bar", "margin",
    "spread", "said"}``; ``said`` is ``met``, ``missed``, or ``tie`` where the margin is
    within the spread over training seeds (max - min; ``None`` with one seed, said so)."""
    s, seeds = fold["scores"], fold["fold_models"]
    cl = s["copy_last"]
    best = {k: max(at(s[b], "f1", k) for b in baselines_of(fold)) for k in ("1", "K")}
    bars: dict[str, tuple[str, str, float]] = {
        "exact mover F1 k=1 > copy-last": ("mover_f1", "1", at(cl, "mover_f1", "1")),
        "exact mover F1 ~1 s > copy-last": ("mover_f1", "K", at(cl, "mover_f1", "K")),
        "F1 k=1 > best baseline": ("f1", "1", best["1"]),
        "F1 ~1 s > best baseline": ("f1", "K", best["K"]),
    }
    tol = "mover_f1_tolerant"
    if fold["moving"]:
        if EGO in s:
            bars["tolerant mover F1 ~1 s > ego-moved map"] = (tol, "K", at(s[EGO], tol, "K"))
        bars["tolerant mover F1 ~1 s > tracker"] = (tol, "K", at(s["tracker"], tol, "K"))
    else:
        bars["tolerant mover F1 k=1 >= copy-last + 0.02"] = (tol, "1", at(cl, tol, "1") + 0.02)
        bars["tolerant mover F1 ~1 s >= 1.5 x copy-last"] = (tol, "K", 1.5 * at(cl, tol, "K"))
        bars["tolerant mover F1 ~1 s > tracker"] = (tol, "K", at(s["tracker"], tol, "K"))
    out = {}
    for name, (key, k, bar) in bars.items():
        values = [at(s[m], key, k) for m in seeds]
        mean = float(np.mean(values))
        # with one seed there is no spread to call a tie by: said so
        spread = max(values) - min(values) if len(values) > 1 else None
        margin = mean - bar
        above = margin >= 0 if ">=" in name else margin > 0
        said = "met" if above else "missed"
        if spread is None:
            said += " (1 seed)"
        elif abs(margin) < spread:
            said = "tie"
        out[name] = {"model": mean, "bar": bar, "margin": margin, "spread": spread, "said": said}
    return out


def collect(out: Path) -> dict[str, Any]:
    folds = {p.stem: read_json(p) for p in sorted((out / "evaluation").glob("*.json"))}
    for fold in folds.values():
        fold["targets"] = targets(fold) if fold["fold_models"] else {}
    sims = {p.stem: read_json(p) for p in sorted((out / "sim").glob("*.json"))}
    return {"folds": folds, "aggregate": aggregate(folds), "sims": sims}


def method_order(fold: dict) -> list[str]:
    order = ["model", *BASELINES, EGO, *REFERENCES]
    return [m for m in order if m == "model" or m in fold["scores"]]


def summary_rows(fold: dict) -> dict[str, dict[str, tuple[float, float]]]:
    """``{method: {"f1_1": (value, half-spread), ...}}`` of a fold, the fold models as one
    ``model`` (mean and half-spread), everything else with a half-spread of 0."""
    rows: dict[str, dict[str, tuple[float, float]]] = {}
    for method in method_order(fold):
        row = {}
        for key in KEYS:
            for k in ("1", "K"):
                if method == "model":
                    row[f"{key}_{k}"] = model_stats(fold["scores"], fold["fold_models"], key, k)
                else:
                    row[f"{key}_{k}"] = (at(fold["scores"][method], key, k), 0.0)
        rows[method] = row
    return rows


def aggregate(folds: dict[str, dict]) -> dict[str, dict[str, dict[str, float]]]:
    """Mean over the folds of each group (all, static, moving) of each method's scores (the
    fold model: the mean over its seeds), with the methods every fold of the group has."""
    groups = {
        "all": list(folds),
        "static": [f for f in folds if not folds[f]["moving"]],
        "moving": [f for f in folds if folds[f]["moving"]],
    }
    out: dict[str, dict[str, dict[str, float]]] = {}
    for group, names in groups.items():
        if not names:
            continue
        rows = [summary_rows(folds[n]) for n in names if folds[n]["fold_models"]]
        if not rows:
            continue
        common = [m for m in rows[0] if all(m in r for r in rows)]
        out[group] = {
            m: {c: float(np.mean([r[m][c][0] for r in rows])) for c in rows[0][m]} for m in common
        }
        out[group]["folds"] = {"n": float(len(rows))}
    return out


def table(study: dict[str, Any]) -> str:
    """Markdown: per held-out recording every method at k = 1 and ~1 s, the aggregates, the
    targets, the people shares and the simulated recordings."""
    cols = [f"{key}_{k}" for k in ("1", "K") for key in KEYS]
    head = (
        "| held-out (K) | method | F1 k=1 | mover F1 k=1 | tolerant k=1 | F1 ~1 s | "
        "mover F1 ~1 s | tolerant ~1 s |\n|---|---|---|---|---|---|---|---|"
    )
    lines = ["## Per fold (fold model: mean ± half-spread over its seeds)", "", head]
    for rec, fold in study["folds"].items():
        if not fold["fold_models"]:
            continue
        seeds = "+".join(fold["fold_models"])
        for method, row in summary_rows(fold).items():
            name = f"head_only ({seeds})" if method == "model" else method
            if method in REFERENCES:
                name += " (in-sample)"
            spread = method == "model" and len(fold["fold_models"]) > 1
            cells = [
                f"{v:.3f} ± {h:.3f}" if spread else f"{v:.3f}" for v, h in (row[c] for c in cols)
            ]
            lines.append(f"| {rec} ({fold['K']}) | {name} | " + " | ".join(cells) + " |")
    lines += ["", "## Mean over folds", "", head.replace("held-out (K)", "folds")]
    for group, rows in study["aggregate"].items():
        n = int(rows["folds"]["n"])
        for method, row in rows.items():
            if method == "folds":
                continue
            cells = [f"{row[c]:.3f}" for c in cols]
            lines.append(f"| {group} ({n}) | {method} | " + " | ".join(cells) + " |")
    lines += ["", "## Issue 44's targets (tie: margin within the seeds' spread)", ""]
    lines += ["| held-out | target | model | bar | margin | spread | said |", "|" + "---|" * 7]
    for rec, fold in study["folds"].items():
        for name, t in fold["targets"].items():
            spread = "–" if t["spread"] is None else f"{t['spread']:.3f}"
            lines.append(
                f"| {rec} | {name} | {t['model']:.3f} | {t['bar']:.3f} | {t['margin']:+.3f} | "
                f"{spread} | {t['said']} |"
            )
    for rec, fold in study["folds"].items():
        if "people" not in fold:
            continue
        k = fold["K"]
        lines += ["", f"## People covered at t+k on {rec} (within 0.3 m)", ""]
        lines += ["| method | " + " | ".join(f"k={i}" for i in range(1, k + 1)) + " |"]
        lines += ["|---|" + "---|" * k]
        for method, got in fold["people"].items():
            shares = ["" if v is None else f"{v:.3f}" for v in got["share"]]
            lines.append(f"| {method} | " + " | ".join(shares) + " |")
        counted = fold["people"]["copy_last"]["counted"]
        lines.append("| people counted | " + " | ".join(str(c) for c in counted) + " |")
        check = ", ".join(f"{lag}: {v:.3f}" for lag, v in fold["people_stamp_check"].items())
        lines += ["", f"On their own scan, by the lag of the stamp (scan periods): {check}"]
    if study["sims"]:
        lines += ["", "## Simulated recordings (region: the true movers' cells)", ""]
        lines += [head.replace("held-out (K)", "recording (K)")]
        for name, sim in study["sims"].items():
            s = sim["scores"]
            for method in s:
                cells = [f"{at(s[method], key, k):.3f}" for k in ("1", "K") for key in KEYS]
                lines.append(f"| {name} ({sim['K']}) | {method} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def summary(study: dict[str, Any]) -> dict[str, Any]:
    """The study at k = 1 and K only (what the research page keeps): per fold each method's
    F1, exact and tolerant mover F1 (the fold models' mean and half-spread), the targets, the
    people shares; the aggregates; the simulated recordings."""
    folds = {}
    for rec, fold in study["folds"].items():
        if not fold["fold_models"]:
            continue
        rows = {
            m: {c: [round(v, 4), round(h, 4)] for c, (v, h) in r.items()}
            for m, r in summary_rows(fold).items()
        }
        folds[rec] = {
            "K": fold["K"],
            "moving": fold["moving"],
            "fold_models": fold["fold_models"],
            "scores": rows,
            "targets": {
                n: {k: (round(v, 4) if isinstance(v, float) else v) for k, v in t.items()}
                for n, t in fold["targets"].items()
            },
        }
        for key in ("people", "people_stamp_check"):
            if key in fold:
                folds[rec][key] = fold[key]
    sims = {
        name: {
            "K": sim["K"],
            "scores": {
                m: {f"{key}_{k}": round(at(row, key, k), 4) for k in ("1", "K") for key in KEYS}
                for m, row in sim["scores"].items()
            },
        }
        for name, sim in study["sims"].items()
    }
    for sim in sims.values():  # the fold models together: mean, min and max
        models = [r for m, r in sim["scores"].items() if m not in (*BASELINES, EGO)]
        if models:
            values = {c: [r[c] for r in models] for c in models[0]}
            sim["fold_models"] = {
                c: [round(float(f(v)), 4) for f in (np.mean, min, max)] for c, v in values.items()
            }
    return {"folds": folds, "aggregate": study["aggregate"], "sims": sims}


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
    markdown = table(study)
    write_summary(args, "movers", study, markdown)
    write_json(out / "summary.json", {"command": args.command, **summary(study)})
    return study


if __name__ == "__main__":
    main()
