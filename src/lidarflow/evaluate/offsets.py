"""Choosing an occupancy-head model's fixed decision offset on recordings
(``lidarflow choose-offset``).

An offset added to the head's logit when deciding trades calibration for cells that change.
Each candidate is scored with fixed decisions beside the baselines, and the one with the largest
summed win margin (:func:`win_margin`, positive exactly where the model wins) is chosen. A model
that chooses its offsets online still decides with it for its first frames.
"""

from __future__ import annotations

import json
import tempfile
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from lidarflow.models.config import DECISION_KEYS
from lidarflow.models.weights import decision_record

if TYPE_CHECKING:
    from lidarflow.data.recording import Recording

__all__ = [
    "BASELINES",
    "DEFAULT_OFFSETS",
    "choose_offset",
    "decided_online",
    "score_offsets",
    "win_margin",
    "with_offset",
]

#: The baselines a model must beat, as `evaluate` names them.
BASELINES = ("copy_last", "temporal_average", "constant_velocity")
#: The candidates tried unless told otherwise (the bundled model's 1.2 among them).
DEFAULT_OFFSETS = (0.0, 0.3, 0.6, 0.9, 1.2)


def win_margin(methods: Mapping[str, Mapping[str, Any]], name: str) -> float:
    """``min(F1 - best baseline F1, changed F1 - best baseline changed F1)`` of method ``name``
    in one recording's report ``methods``; a metric with nothing to find counts as 0."""

    def value(method: str, metric: str) -> float:
        return float(methods[method].get(metric) or 0.0)

    best_f1 = max(value(b, "f1") for b in BASELINES)
    best_changed = max(value(b, "changed_f1") for b in BASELINES)
    return min(value(name, "f1") - best_f1, value(name, "changed_f1") - best_changed)


def decided_online(card: Mapping[str, Any]) -> bool:
    """Whether the model described by ``card`` (its model.json) chooses its offsets online."""
    return decision_record(dict(card))["online"]


def with_offset(card: Mapping[str, Any], offset: float, online: bool = False) -> dict[str, Any]:
    """A copy of the model.json ``card`` deciding with the fixed ``offset`` (online where
    ``online``), without the decision keys older files kept among the model's kwargs."""
    kwargs = {k: v for k, v in (card.get("model_kwargs") or {}).items() if k not in DECISION_KEYS}
    kept = {k: v for k, v in card.items() if k not in ("weights_path", "weights_sha256")}
    decision = {"offset": float(offset), "online": bool(online)}
    return {**kept, "model_kwargs": kwargs, "decision": decision}


def choose_offset(
    recordings: Sequence[Mapping[str, Any]], names: Mapping[float, str]
) -> tuple[float, dict[float, float]]:
    """The offset (``names``: offset -> method name) whose summed win margin over the report's
    ``recordings`` is largest (the first of equals), and every offset's sum."""
    totals = {
        offset: sum(win_margin(entry["methods"], name) for entry in recordings)
        for offset, name in names.items()
    }
    return max(totals, key=lambda o: totals[o]), totals


def score_offsets(
    named: Sequence[tuple[str, Recording]],
    card: Mapping[str, Any],
    weights: Path,
    offsets: Sequence[float],
    grid: Any,
    warmup: int,
    progress: Callable[[str, int], Any] | None = None,
) -> tuple[dict[str, Any], dict[float, str]]:
    """The `evaluate` report of the model (``card`` with ``weights``) deciding with each of
    the ``offsets`` on the ``named`` recordings, and each offset's method name in it."""
    from lidarflow.evaluate.evaluation import evaluate_and_report
    from lidarflow.evaluate.methods import methods_and_config

    with tempfile.TemporaryDirectory() as tmp:
        folders: dict[float, Path] = {}
        for offset in offsets:
            folder = Path(tmp) / f"offset_{offset:g}"
            folder.mkdir()
            (folder / "model.json").write_text(json.dumps(with_offset(card, offset)))
            (folder / "model.safetensors").symlink_to(weights.resolve())
            folders[offset] = folder
        methods, config = methods_and_config(list(folders.values()), res=grid.res)
        config.update({"warmup": warmup, "grid": grid.to_dict()})
        report = evaluate_and_report(named, methods, grid, warmup, config, None, progress)
    return report, {o: f.name for o, f in folders.items()}
