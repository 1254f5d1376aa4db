"""F1 per prediction horizon: how well a model predicts 1..K frames ahead.

The model streams as in :mod:`lidarflow.evaluate.stream` (one step per frame, state carried).
After frame ``t`` (``t >= warmup``) it also rolls forward ``K - 1`` more steps from a copy of
its state, feeding back its own predicted map with the visibility of frame ``t`` — exactly what
:class:`lidarflow.predict.Predictor` does for ``horizon=K`` — and the prediction ``k`` steps
ahead is scored (F1 at 0.4) against ``O^{t+k}``. Copy-last's ``k``-step prediction is ``O^t``.
Frames ``t`` without a frame ``t + K``, or with a gap in time before one of ``t + 1 .. t + K``
(:func:`lidarflow.data.gaps.frames_after_gaps`), are not scored, so every horizon sees the same
frames.

A model with an online decision (``decisions``, :mod:`lidarflow.predict.decision`) decides its
next map with it, as in the streaming evaluation, and the roll-out feeds back that decided map,
each step re-decided with the same choice (offsets and map). Fed back at a fixed offset the
offset compounds: the bundled v6 at its fixed 0.9 fell below copy-last on demo_stationary at
every k, and with its online choice fed back it is above at every k
(docs/results/accuracy/horizon_bundled_v6_online.json).

Ego-motion models get each frame's motion (``motions``: the recording's odometry, or the motion
matched from its scans, NaN where none is known) and roll forward assuming the same motion again,
as the Predictor does; a model that may run without poses checks it against the scans first
(:class:`lidarflow.motion.odometry.OdometryCheck`) and replaces odometry that disagrees by
the scans' own motion, as in the streaming evaluation.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

import numpy as np
import torch

from lidarflow.data.blocks import Frames
from lidarflow.errors import EvaluateError
from lidarflow.evaluate.metrics import THRESHOLD, Counts, confusion
from lidarflow.models.recurrent import RecurrentMapModel
from lidarflow.models.streaming import model_input
from lidarflow.motion.odometry import OdometryCheck
from lidarflow.motion.pacing import paced_motion
from lidarflow.motion.scanmatch import ScanOdometry, checked_motion
from lidarflow.predict.decision import OnlineDecision, moved_last_map

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


@torch.no_grad()
def horizon_f1(
    occupancy: Frames,
    visibility: Frames,
    models: dict[str, RecurrentMapModel],
    horizon: int,
    warmup: int = 10,
    progress: Callable[[int], None] | None = None,
    motions: np.ndarray | None = None,
    decisions: dict[str, OnlineDecision] | None = None,
    returns: Sequence[np.ndarray] | None = None,
    motions_from_poses: bool = False,
    res: float = 0.1,
    subcell: Frames | None = None,
    gaps: Sequence[int] = (),
    paces: Mapping[int, float] | None = None,
) -> dict[str, list[float]]:
    """``{"copy_last": [F1 at k = 1..K], name: [...] for each model}`` on maps ``(N, H, W)``.

    ``progress(1)`` is called after every model step on a recorded frame. ``motions``
    ``(N, 3)`` (cells, radians; NaN: unknown) go to ego-motion models; without them those run
    uncompensated. ``decisions``: the online decision of the models that have one (reset here,
    then updated on every frame). ``motions_from_poses``: the motions are odometry, which a
    model that may run without poses replaces by the scans' own motion where they disagree
    (from the maps, and each frame's ``returns`` where given, on a grid of ``res`` metres), as
    the streaming evaluation and the Predictor do; else they are only checked. ``subcell``
    ``(N, 2, H, W)``: where each frame's returns lie inside their cells, for models with
    ``subcell_input`` (a predicted map fed back gets zeros: it has no returns). ``gaps``: the
    frames that follow a gap in time (no roll-out across one is scored; states carry on);
    ``paces`` (:func:`lidarflow.motion.pacing.paces_after_long_steps`): after a long step (a gap,
    scans dropped), the guess of the next motion, and each step of the roll-out, is the last
    motion scaled to one typical step, as the Predictor's."""
    n = len(occupancy)
    scored = scored_frames(n, horizon, warmup, gaps)
    scoring = set(scored)
    copy = [Counts() for _ in range(horizon)]
    for t in scored:
        for k in range(horizon):
            copy[k] = copy[k] + confusion(occupancy[t], occupancy[t + 1 + k])
    result = {"copy_last": [c.f1 for c in copy]}
    for name, model in models.items():
        ego = bool(getattr(model, "ego_motion", False))
        optional = bool(getattr(model, "poses_optional", False))
        check = OdometryCheck() if optional else None
        scans = ScanOdometry(res) if optional else None
        counts = [Counts() for _ in range(horizon)]
        online = (decisions or {}).get(name)
        if online is not None:
            online.reset()
        h, w = np.shape(occupancy[0])[-2:]
        state = model.init_state(1, h, w)
        for t in range(n - horizon):
            extra = None if subcell is None else subcell[t]
            maps = torch.from_numpy(model_input(model, occupancy[t], visibility[t], extra))[None]
            known = _known(motions, t) if ego else None
            pace = (paces or {}).get(t)
            if check is not None and ego:
                points = None if returns is None else returns[t]
                known, _ = checked_motion(
                    check, scans, occupancy[t], known, motions_from_poses, points, pace
                )
            moved, guess = (
                None if m is None else torch.from_numpy(m).float()[None]
                for m in (known, paced_motion(known, pace))
            )
            out, state = model.step(maps, state, moved, guess) if ego else model.step(maps, state)
            # each step of the roll-out is one typical step
            ahead = (moved if guess is None else guess,) if ego else ()
            if progress is not None:
                progress(1)
            probability = model.predict_next(maps, out)
            if online is not None:  # every frame: it scores itself on the stream
                decided = online.update(
                    probability[0, 0].numpy(), occupancy[t], visibility[t], _moved(maps, out)
                )
                probability = torch.from_numpy(decided)[None, None]
            if t not in scoring:
                continue
            rolled = state
            for k in range(horizon):
                if k > 0:
                    fed = torch.cat([probability, maps[:, 1:2], torch.zeros_like(maps[:, 2:])], 1)
                    out_k, rolled = model.step(fed, rolled, *ahead)
                    probability = model.predict_next(fed, out_k)
                    if online is not None:
                        decided = online.apply(
                            probability[0, 0].numpy(), fed[0, 0].numpy(), _moved(fed, out_k)
                        )
                        probability = torch.from_numpy(decided)[None, None]
                predicted = probability[0, 0].numpy() >= THRESHOLD
                counts[k] = counts[k] + confusion(predicted, occupancy[t + 1 + k])
        result[name] = [c.f1 for c in counts]
    return result


def _moved(maps: torch.Tensor, out: torch.Tensor) -> np.ndarray:
    """The occupancy of ``maps`` moved into the next frame by the step's backward flow."""
    flow = out[0, 0:2].numpy() if out.shape[1] >= 4 else None
    return moved_last_map(maps[0, 0].numpy(), flow)


def _known(motions: np.ndarray | None, t: int) -> np.ndarray | None:
    """Frame ``t``'s motion, ``None`` where there are none or it is NaN (unknown)."""
    if motions is None or np.isnan(motions[t]).any():
        return None
    return motions[t]
