"""Scoring for the studies through the library, as `lidarflow evaluate` scores: models beside
the baselines, streaming over recordings, and the counts of a stretch of a stream.

Only public functions of :mod:`lidarflow.evaluate` are called, so that a study follows the
library when its modules move."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from lidarflow.baselines import (
    TA_THRESHOLD,
    TA_WINDOW,
    CopyLastEgo,
)
from lidarflow.data.recording import Recording
from lidarflow.evaluate.evaluation import evaluate_and_report
from lidarflow.evaluate.methods import methods_and_config
from lidarflow.evaluate.metrics import THRESHOLD, Counts, confusion
from lidarflow.evaluate.runner import evaluate_recording
from lidarflow.scan import GridSpec
from lidarflow.viz.evaluation import ReportFigures

#: frames per recording that only warm the methods' state up (`lidarflow evaluate`'s default)
WARMUP = 10
Source = str | Path | None  # a model folder or file, "bundled", or None: the bundled model


def methods_for(
    models: Mapping[str, Source],
    online: bool = False,
    ta_window: int = TA_WINDOW,
    ta_threshold: float = TA_THRESHOLD,
    res: float = 0.1,
    device: str = "cpu",
) -> list[Any]:
    """The baselines and one method per model (``{name: source}``), as `lidarflow
    evaluate` builds them; with an ego-motion model, ``copy_last_ego`` beside it (a reference,
    never judged). ``online``: each model also with the decision rule it was not built with
    (``NAME_online`` or ``NAME_fixed``, :func:`studies.harness.split_online`)."""
    sources, names = list(models.values()), list(models)
    return methods_and_config(
        sources, ta_window, ta_threshold, online=online, res=res, names=names, device=device
    )[0]


def evaluate(
    recordings: Sequence[tuple[str, Recording]],
    models: Mapping[str, Source],
    online: bool = False,
    warmup: int = WARMUP,
    report_dir: Path | None = None,
    grid: GridSpec | None = None,
    horizon: int = 1,
    device: str = "cpu",
    on_ahead: Callable[[str, str, int, np.ndarray], None] | None = None,
) -> dict[str, Any]:
    """`lidarflow evaluate`'s report of ``models`` beside the baselines on ``recordings``
    (``(name, recording)`` pairs): ``{"recordings": [{"path", "methods", ...}], "overall",
    "against_baselines"}``; with ``report_dir`` its figures and HTML report too; with
    ``horizon`` K > 1 every method rolled 1..K frames ahead too (``horizon_f1`` etc., as
    ``--horizon``); ``device``: where PyTorch models run; ``on_ahead``: each scored prediction
    1..K ahead (:func:`lidarflow.evaluate.evaluation.score_one`'s)."""
    grid = grid or GridSpec()
    methods = methods_for(models, online, res=grid.res, device=device)
    config = {
        "warmup": warmup,
        "grid": grid.to_dict(),
        "models": {name: None if s is None else str(s) for name, s in models.items()},
        "online_decision_both_ways": online,
        "no_verdict": [m.name for m in methods if isinstance(m, CopyLastEgo)],
    }
    figures = None if report_dir is None else ReportFigures(report_dir)
    return evaluate_and_report(
        recordings, methods, grid, warmup, config, figures, horizon=horizon, on_ahead=on_ahead
    )


def evaluate_one(
    recording: Recording, name: str, source: Source, online: bool = False, warmup: int = WARMUP
) -> dict[str, dict]:
    """The methods' scores (:func:`evaluate`) of one model on one recording."""
    report = evaluate([(name, recording)], {"model": source}, online, warmup)
    return report["recordings"][0]["methods"]


def drives(paths: Sequence[Path], sim_frames: int) -> dict[str, Recording]:
    """The recordings at ``paths`` by name, or by default a real drive with odometry
    (general_tracking_moving_1) and a simulated one of ``sim_frames`` frames (seed 7)."""
    from lidarflow.data import load_any
    from lidarflow.sim import SimConfig, simulate
    from studies.harness import DATA, stem

    if paths:
        return {stem(path): load_any(path) for path in paths}
    return {
        "general_tracking_moving_1": load_any(DATA / "general_tracking_moving_1.bag.zip"),
        "simulated_drive": simulate(sim_frames, seed=7, config=SimConfig(scenario="dynamic")),
    }


def kept_frames(recording: Recording, kept: Sequence[int]) -> Recording:
    """The frames ``kept`` (indices, in order) of ``recording``, with their poses."""
    poses = None if recording.poses is None else recording.poses[list(kept)]
    return Recording.from_scans([recording.scan(i) for i in kept], poses, recording.meta)


def early_late(start: int, early: int) -> Callable[[int], str | None]:
    """The parts of :func:`scores_from` for the predictions made from frame ``start`` on: the
    first ``early`` (``early``) and the rest (``late``)."""
    return lambda t: None if t < start else ("early" if t < start + early else "late")


def scores_from(
    recording: Recording, methods: list, part: Callable[[int], str | None]
) -> dict[str, dict[str, Counts]]:
    """Stream ``methods`` over ``recording`` as `lidarflow evaluate` does, and count each
    prediction (made at frame ``t``) in ``part(t)`` (``None``: not counted), over all cells
    (``<part>_all``) and the changed ones (``<part>_changed``), per method."""
    occupancy, _ = recording.maps(GridSpec())
    counts: dict[str, dict[str, Counts]] = {}

    def keep(name: str, t: int, probability: np.ndarray, _flow: object) -> None:
        where = part(t)
        if where is None:
            return
        predicted, target = probability >= THRESHOLD, occupancy[t + 1].astype(bool)
        changed = occupancy[t].astype(bool) != target
        mine = counts.setdefault(name, {})
        for key, mask in ((f"{where}_all", None), (f"{where}_changed", changed)):
            mine[key] = mine.get(key, Counts()) + confusion(predicted, target, mask)

    evaluate_recording(recording, methods, warmup=0, on_prediction=keep)
    return counts


def add_counts(tree: dict, case: str, got: dict) -> None:
    """Add ``got`` (:func:`scores_from`'s) into ``tree[case]``."""
    for method, parts in got.items():
        slot = tree.setdefault(case, {}).setdefault(method, {})
        for part, c in parts.items():
            slot[part] = slot[part] + c if part in slot else c


def f1_table(tree: dict) -> dict:
    """``tree`` of counts as F1 to 4 decimals."""
    return {
        case: {m: {p: round(c.f1, 4) for p, c in parts.items()} for m, parts in by_m.items()}
        for case, by_m in tree.items()
    }
