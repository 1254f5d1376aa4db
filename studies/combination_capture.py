"""The online combination's candidates kept as it streams a recording, for the ceiling study
(:mod:`studies.combination_ceiling`): every frame, each candidate's decided map 1 and K ahead,
its rare cells and its causal mover region, beside the truths, `evaluate`'s mover region and
every method's decided maps."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from lidarflow.data.sources import load_any
from lidarflow.evaluate.evaluation import score_one
from lidarflow.evaluate.methods import methods_and_config
from lidarflow.evaluate.runner import recording_inputs
from lidarflow.evaluate.stream import mover_region
from lidarflow.online.combination import Combination, candidate_maps
from lidarflow.online.experts import ExpertMaps, Experts
from lidarflow.scan import GridSpec
from studies.harness import write_arrays
from studies.movers import horizon_of

__all__ = ["Recorded", "capture"]


class KeptExperts(ExpertMaps):
    """The experts, the last frame's kept."""

    last: Experts

    def of(self, *args: Any, **kwargs: Any) -> Experts:
        self.last = super().of(*args, **kwargs)
        return self.last


class Recorded(Combination):
    """The combination, each frame's candidates 1 and ``K`` ahead (decided, bit-packed), its
    rare cells and its causal mover region kept."""

    def __init__(self, horizon: int) -> None:
        super().__init__(horizon)
        self.experts = KeptExperts(horizon)
        self.frames: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []

    def step(self, *args: Any, **kwargs: Any) -> Any:
        out = super().step(*args, **kwargs)
        experts = self.experts.last
        ks = (0, self.horizon - 1)
        candidates = [
            candidate_maps(self.stacks[k], experts.maps[:, k], experts.rare[k]) for k in ks
        ]
        self.frames.append(
            (
                np.packbits(np.stack(candidates), axis=-1),
                np.packbits(experts.rare[list(ks)], axis=-1),
                np.packbits(experts.region, axis=-1),
            )
        )
        return out


def capture(path: Path, model: Path | None, target: Path) -> dict[str, Any]:
    """Stream ``path`` with ``model`` (``None``: the bundled one) combined; write the
    candidates, the truths, evaluate's mover region and every method's decided maps 1 and K
    ahead to ``target`` (npz). Returns evaluate's horizon tables of the stream."""
    recording = load_any(path)
    horizon = horizon_of(recording)
    methods, _ = methods_and_config([model], names=["model"], combine=horizon)
    combined = next(m for m in methods if m.name == "model_combined")
    combined.combination = recorded = Recorded(horizon)
    ahead: dict[str, dict[int, np.ndarray]] = {}

    def keep(_name: str, method: str, t: int, predicted: Any) -> None:
        p = np.asarray(predicted)
        ahead.setdefault(method, {})[t] = np.packbits(np.stack([p[0], p[-1]]) >= 0.4, axis=-1)

    grid = GridSpec()
    scored = score_one(path.name, recording, methods, grid, 10, horizon, on_ahead=keep)
    inputs = recording_inputs(recording, grid, methods)
    region = mover_region(recording, grid, inputs)
    frames = range(len(inputs.occupancy))
    occupied = np.stack([np.asarray(inputs.occupancy[t], bool) for t in frames])
    shape = occupied.shape[1:]
    regions = np.stack([region(t) if region else np.zeros(shape, bool) for t in frames])
    frames_scored = sorted(ahead["copy_last"])
    arrays = {
        "horizon": np.array(horizon),
        "scored": np.array(frames_scored),
        "occupied": np.packbits(occupied, axis=-1),
        "region": np.packbits(regions, axis=-1),
        "candidates": np.stack([f[0] for f in recorded.frames]),
        "rare": np.stack([f[1] for f in recorded.frames]),
        "causal_region": np.stack([f[2] for f in recorded.frames]),
        **{f"method/{m}": np.stack([by_t[t] for t in frames_scored]) for m, by_t in ahead.items()},
    }
    write_arrays(target, arrays)  # a killed capture leaves no file the tables would read
    return scored.horizon or {}
