"""Scores per prediction horizon: how well a method predicts 1..K frames ahead.

After each frame :func:`scored_frames` names, every method is rolled forward from a copy of
its state (:func:`rolled_forward`) and its output ``k`` steps ahead is scored against
``O^{t+k}`` (:class:`HorizonScore`): F1 and changed-cell F1 at 0.4, WMSE and SSIM, and the mover
metric inside the dynamic region of frame ``t + k``. Every ``k`` scores the same frames: those
after the warm-up with ``K`` frames after them and no gap in time in between, so the ``k = 1``
column is not the main table's (:func:`horizon_note` says so).
"""

from __future__ import annotations

import copy
import dataclasses
from array import array
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from lidarflow.baselines import FrameInputs, Method
from lidarflow.data.blocks import Frames
from lidarflow.errors import EvaluateError
from lidarflow.evaluate.metrics import THRESHOLD, Counts, confusion
from lidarflow.evaluate.movers import MoverScore
from lidarflow.evaluate.peer_metrics import SSIM_WINDOW, ssim, wmse

__all__ = [
    "HorizonScore",
    "check_horizon",
    "horizon_entry",
    "horizon_note",
    "rolled_forward",
    "scored_frames",
]


def check_horizon(frames: int, horizon: int, warmup: int = 10, name: str = "the recording") -> None:
    """Raise :class:`EvaluateError` for a ``horizon`` below 1 or one that a recording of
    ``frames`` frames cannot use: no frame after the ``warmup`` has a frame ``horizon`` ahead.
    ``predict`` and ``live`` check with no warm-up, before a roll-out per scan runs for hours
    to predict frames that are not there."""
    if horizon < 1:
        raise EvaluateError(f"horizon must be >= 1, got {horizon}")
    if frames < warmup + horizon + 1:
        has = f"{frames} frame{'s' * (frames != 1)}"
        first = f"{warmup} to warm up" if warmup else "one to predict from"
        lower = "--horizon or --warmup" if warmup else "--horizon"
        raise EvaluateError(
            f"{name}: too short for --horizon {horizon}: needs at least "
            f"{warmup + horizon + 1} frames ({first}, then {horizon} ahead), it has {has}; "
            f"lower {lower}, or leave it out"
        )


def scored_frames(
    frames: int,
    horizon: int,
    warmup: int = 10,
    gaps: Sequence[int] = (),
    name: str = "the recording",
) -> list[int]:
    """The frames ``t``, in order, whose predictions 1..``horizon`` ahead are scored on a
    recording of ``frames`` frames with ``gaps`` (the frames after a gap in time). Raises
    :class:`EvaluateError` naming ``name`` when there are none."""
    check_horizon(frames, horizon, warmup, name)
    after_gap = np.zeros(frames + 1, bool)
    after_gap[[g for g in gaps if 0 < g < frames]] = True
    crossed = np.convolve(after_gap, np.ones(horizon, int))  # any gap in t + 1 .. t + horizon
    scored = [t for t in range(warmup, frames - horizon) if not crossed[t + horizon]]
    if not scored:
        raise EvaluateError(
            f"{name}: no frame has {horizon} frames after it without a gap in time; lower "
            "--horizon or leave it out"
        )
    return scored


class HorizonScore:
    """One method's sums per step ``k``: F1 and changed-cell F1 counts, WMSE, SSIM (none on
    a grid under 11 x 11 cells) and, with a ``region`` (``t ->`` frame ``t``'s dynamic
    region), the mover metric."""

    def __init__(
        self,
        horizon: int,
        shape: tuple[int, ...],
        region: Callable[[int], np.ndarray] | None = None,
    ) -> None:
        self.counts = [Counts() for _ in range(horizon)]
        self.changed = [Counts() for _ in range(horizon)]
        self.region = region
        self.movers = [MoverScore() for _ in range(horizon)]
        # the tolerant counts K ahead, frame by frame (the verdict's margin there, its interval)
        self.last_mover_rows = array("i")
        self.wmse = np.zeros(horizon)
        self.ssim = np.zeros(horizon) if min(shape) >= SSIM_WINDOW else None
        self.frames = 0

    def add(self, predicted: np.ndarray, occupancy: Frames, t: int) -> None:
        """``predicted`` ``(K, H, W)``: the outputs 1..K ahead of frame ``t``, scored against
        ``occupancy[t + 1 .. t + K]``."""
        truths = np.stack([occupancy[t + 1 + k] for k in range(len(predicted))])
        for k, (decided, truth) in enumerate(zip(predicted, truths, strict=True)):
            self.counts[k] = self.counts[k] + confusion(decided >= THRESHOLD, truth)
            changed = np.asarray(occupancy[t], bool) != np.asarray(truth, bool)
            self.changed[k] = self.changed[k] + confusion(decided >= THRESHOLD, truth, changed)
            if self.region is not None:
                tolerant = self.movers[k].add(decided, truth, self.region(t + 1 + k))
                if k == len(self.movers) - 1:
                    self.last_mover_rows.extend(tolerant.row())
        self.wmse += wmse(predicted, truths)
        if self.ssim is not None:
            self.ssim += ssim(predicted, truths)
        self.frames += 1

    def means(self) -> dict[str, list[Any]]:
        """``{"f1": [k = 1..K], "changed_f1", "wmse", "ssim"}``, with a region also
        ``mover_f1``, ``mover_f1_tolerant``, ``mover_auc`` (``None`` where the region held one
        class only), ``mover_soft_iou`` and ``mover_true_cells``."""
        out: dict[str, list[Any]] = {"f1": _f1(self.counts), "changed_f1": _f1(self.changed)}
        out["wmse"] = [float(v) for v in self.wmse / max(self.frames, 1)]
        if self.ssim is not None:
            out["ssim"] = [float(v) for v in self.ssim / max(self.frames, 1)]
        if self.region is not None:
            summaries = [m.summary() for m in self.movers]
            for key in ("f1", "f1_tolerant", "auc", "soft_iou", "true_cells"):
                out[f"mover_{key}"] = [s[key] for s in summaries]
        return out


def rolled_forward(
    method: Method,
    prediction: np.ndarray,
    visibility: np.ndarray,
    given: FrameInputs,
    horizon: int,
) -> np.ndarray:
    """``method``'s predictions ``(K, H, W)`` 1..``horizon`` frames ahead of the frame it was
    just given (with ``visibility`` and ``given``; ``prediction``: what ``update`` returned),
    leaving ``method`` as it was: a method's own ``ahead(horizon)`` (a model's,
    :meth:`~lidarflow.evaluate.model_method.ModelMethod.ahead`; the tracker's), else its
    decided prediction fed back to a copy of it with the same visibility and motion."""
    native = getattr(method, "ahead", None)
    if callable(native):  # predicts k ahead itself (the tracker moves each object k steps)
        return np.stack(native(horizon))
    rolled, ahead = copy.deepcopy(method), [prediction]
    fed_given = dataclasses.replace(given, next_motion=None)
    for _ in range(horizon - 1):
        fed = (ahead[-1] >= THRESHOLD).astype(np.float32)
        ahead.append(rolled.update(fed, visibility, fed_given))
    return np.stack(ahead)


def horizon_entry(scores: dict[str, dict[str, list[Any]]], frames: int) -> dict[str, Any]:
    """A recording's ``horizon_*`` report keys from its horizon ``scores``, with the
    ``frames`` scored at every ``k``; ``horizon_undefined: ["mover_f1"]`` where no true cell
    lay in the region ``K`` ahead."""
    scores = dict(scores)
    true_cells = scores.pop("mover_true_cells", None)
    keys: dict[str, Any] = {f"horizon_{key}": scored for key, scored in scores.items()}
    keys["horizon_frames_evaluated"] = frames
    if true_cells is not None and not true_cells["copy_last"][-1]:
        keys["horizon_undefined"] = ["mover_f1"]
    return keys


def horizon_note(entry: Mapping[str, Any]) -> str:
    """The line over a recording's horizon tables: the frames they score beside the main
    table's, so that the ``k = 1`` column and the main table are not read as one number."""
    k = len(entry["horizon_f1"]["copy_last"])
    frames, main = entry.get("horizon_frames_evaluated"), entry["frames_evaluated"]
    if frames is None or frames == main:
        return f"horizon tables: the {main} frames of the main table, at every k"
    return (
        f"horizon tables: {frames} frames at every k (those with {k} frames after them, no gap "
        f"in between); the main table scores {main}, so the k=1 columns are not its numbers"
    )


def _f1(counts: list[Counts]) -> list[float]:
    return [c.f1 for c in counts]
