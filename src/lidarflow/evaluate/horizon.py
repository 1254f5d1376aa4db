"""F1 per prediction horizon: how well a model predicts 1..K frames ahead.

Each model streams as in :mod:`lidarflow.evaluate.stream` (the same
:class:`~lidarflow.evaluate.model_method.ModelMethod`, fed the same inputs, one step per frame,
state carried). After frame ``t`` (``t >= warmup``) it also rolls forward ``K - 1`` more steps
from a copy of its state (:meth:`lidarflow.predict.engine.Engine.roll`, what
:class:`lidarflow.predict.Predictor` does for ``horizon=K``), and the prediction ``k`` steps
ahead is scored (F1 at 0.4) against ``O^{t+k}``. Copy-last's ``k``-step prediction is ``O^t``.
Frames ``t`` without a frame ``t + K``, or with a gap in time before one of ``t + 1 .. t + K``
(:func:`lidarflow.data.gaps.frames_after_gaps`), are not scored, so every horizon sees the same
frames.

A model with an online decision (:mod:`lidarflow.predict.decision`) decides its next map with
it, and the roll-out feeds back that decided map, each step re-decided with the same choice
(offsets and map). Fed back at a fixed offset the offset compounds: the bundled v6 at its fixed
0.9 fell below copy-last on demo_stationary at every k, and with its online choice fed back it
is above at every k.

Ego-motion models roll forward assuming one more typical step of the same motion, as the
Predictor does.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

import numpy as np

from lidarflow.data.blocks import Frames
from lidarflow.errors import EvaluateError
from lidarflow.evaluate.metrics import THRESHOLD, Counts, confusion
from lidarflow.evaluate.model_method import ModelMethod
from lidarflow.evaluate.stream import method_inputs

__all__ = ["horizon_f1", "scored_frames"]


def scored_frames(
    frames: int,
    horizon: int,
    warmup: int = 10,
    gaps: Sequence[int] = (),
    name: str = "the recording",
) -> list[int]:
    """The frames ``t`` (in order) whose predictions 1..``horizon`` ahead are scored on a
    recording of ``frames`` frames with ``gaps`` (the frames after a gap in time). Raises
    :class:`EvaluateError` naming ``name`` when there are none; the command line checks every
    recording with it before the long work on any of them."""
    if horizon < 1:
        raise EvaluateError(f"horizon must be >= 1, got {horizon}")
    if frames < warmup + horizon + 1:
        has = f"{frames} frame{'s' * (frames != 1)}"
        raise EvaluateError(
            f"{name}: too short for --horizon {horizon}: needs at least "
            f"{warmup + horizon + 1} frames ({warmup} to warm up, then {horizon} ahead), it has "
            f"{has}; lower --horizon or --warmup, or leave it out"
        )
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


def horizon_f1(
    occupancy: Frames,
    visibility: Frames,
    methods: Sequence[ModelMethod],
    horizon: int,
    warmup: int = 10,
    progress: Callable[[int], None] | None = None,
    motions: np.ndarray | None = None,
    returns: Sequence[np.ndarray] | None = None,
    motions_from_poses: bool = False,
    subcell: Frames | None = None,
    gaps: Sequence[int] = (),
    paces: Mapping[int, float] | None = None,
) -> dict[str, list[float]]:
    """``{"copy_last": [F1 at k = 1..K], name: [...] for each model}`` on maps ``(N, H, W)``.

    ``progress(1)`` is called after every model step on a recorded frame. The other inputs are
    :func:`~lidarflow.evaluate.stream.evaluate_maps`' (the motions, returns, sub-cell maps and
    paces each method takes); ``gaps``: the frames that follow a gap in time (no roll-out
    across one is scored; states carry on)."""
    n = len(occupancy)
    scored = scored_frames(n, horizon, warmup, gaps)
    scoring = set(scored)
    copy = [Counts() for _ in range(horizon)]
    for t in scored:
        for k in range(horizon):
            copy[k] = copy[k] + confusion(occupancy[t], occupancy[t + 1 + k])
    result = {"copy_last": [c.f1 for c in copy]}
    for method in methods:
        counts = [Counts() for _ in range(horizon)]
        method.reset()
        for t in range(n - horizon):
            extra = method_inputs(method, t, motions, returns, motions_from_poses, subcell, paces)
            method.update(occupancy[t], visibility[t], **extra)  # type: ignore[arg-type]
            if progress is not None:
                progress(1)
            if t not in scoring:
                continue
            assert method.last is not None
            for k, probability in enumerate(method.engine.roll(method.last, horizon)):
                counts[k] = counts[k] + confusion(probability >= THRESHOLD, occupancy[t + 1 + k])
        result[method.name] = [c.f1 for c in counts]
    return result
