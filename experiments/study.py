"""What the issue-11 experiment scripts share: the `lidarflow` command runner, reading an
evaluate report's model and baselines, the one rule for "wins" (F1 above the best baseline's
and changed-cell F1 above every baseline's), and scoring a stretch of a stream."""

from __future__ import annotations

import shlex
import subprocess
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from lidarflow.data.recording import Recording

BASELINES = ("copy_last", "temporal_average", "constant_velocity")
METRICS = ("f1", "changed_f1", "ap")
# Scored beside ego-motion models on recordings with poses; reported, not counted in a verdict
# (the baselines need no odometry).
REFERENCES = ("copy_last_ego", "copy_last_ego_oracle")
# The seven development recordings of ../shared/data, in the order the studies list them.
DEVELOPMENT = (
    "positive_1.bag", "positive_2.bag", "positive_3.bag", "positive_4.bag",
    "demo_stationary_simple_environment.bag", "datmo_overtakes.bag",
    "general_tracking_moving_1.bag.zip",
)  # fmt: skip


def lidarflow(*args: str) -> None:
    print("$ lidarflow " + shlex.join(args), flush=True)
    subprocess.run([sys.executable, "-m", "lidarflow.cli", *args], check=True)


def stem(path: Path) -> str:
    name = path.name
    for suffix in (".bag.zip", ".bag", ".mcap", ".npz"):
        if name.endswith(suffix):
            return name[: -len(suffix)]
    return name


def best_baselines(baselines: dict[str, dict[str, float]]) -> tuple[float, float]:
    """The best F1 and the best changed-cell F1 among the baselines (not necessarily one's)."""
    best_f1 = max(b["f1"] for b in baselines.values())
    return best_f1, max(b["changed_f1"] for b in baselines.values())


def margins(scores: dict) -> tuple[float, float]:
    """The model's F1 and changed-cell F1 less the best baselines' (:func:`best_baselines`), of
    ``scores`` as :func:`model_and_baselines` gives them."""
    best_f1, best_changed = best_baselines(scores["baselines"])
    return scores["model"]["f1"] - best_f1, scores["model"]["changed_f1"] - best_changed


def model_and_baselines(methods: dict[str, dict]) -> dict[str, dict]:
    """``{"model": ..., "baselines": {name: ...}}`` (METRICS only) from an evaluate report's
    methods of one recording that holds one model beside the baselines."""
    # Besides the baselines an evaluation may hold references the verdict does not count
    # (copy_last_ego, scored beside an ego-motion model on a recording with poses).
    (model_key,) = [k for k in methods if k not in (*BASELINES, *REFERENCES)]
    scores = {
        "model": {k: methods[model_key][k] for k in METRICS},
        "baselines": {b: {k: methods[b][k] for k in METRICS} for b in BASELINES},
    }
    if refs := {r: {k: methods[r][k] for k in METRICS} for r in REFERENCES if r in methods}:
        scores["references"] = refs
    return scores


def split_online(methods: dict[str, dict]) -> tuple[dict[str, dict], dict | None]:
    """An ``evaluate --online-decision`` report's methods of one recording, split into those
    with the model's own rule (the offsets chosen online) and the other rule's scores (the
    fixed offsets; ``None`` when the report holds one rule only)."""
    # The model's own rule is NAME; the other is NAME_fixed, or NAME when it has NAME_online.
    if fixed_keys := [k for k in methods if k.endswith("_fixed")]:
        (other,) = fixed_keys
    elif online_keys := [k for k in methods if k + "_online" in methods]:
        (other,) = online_keys
    else:
        return dict(methods), None
    kept = {k: v for k, v in methods.items() if k != other}
    return kept, methods[other]


def verdict(model: dict[str, float], baselines: dict[str, dict[str, float]]) -> str:
    best_f1, best_changed = best_baselines(baselines)
    wins_f1, wins_changed = model["f1"] > best_f1, model["changed_f1"] > best_changed
    if wins_f1 and wins_changed:
        return "wins"
    if wins_f1:
        return "F1 only"
    if wins_changed:
        return "changed only"
    return "loses"


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
) -> dict[str, dict[str, object]]:
    """Stream ``methods`` over ``recording`` as ``lidarflow evaluate`` does, and count each
    prediction (made at frame ``t``) in ``part(t)`` (``None``: not counted), over all cells
    (``<part>_all``) and the changed ones (``<part>_changed``), per method
    (:class:`lidarflow.evaluate.metrics.Counts`)."""
    # here, not at the top: the scripts that only read reports need no PyTorch
    from lidarflow.evaluate.metrics import THRESHOLD, Counts, confusion
    from lidarflow.evaluate.stream import evaluate_recording
    from lidarflow.scan import GridSpec

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
