"""Training windows that start where streaming leaves the occupancy head's memories
(``data.memories_from_stream``).

The memories average past maps over hundreds of frames, longer than a window, and depend on the
maps and motions alone, not on any weight: so they are streamed once per recording, and each
window starts from the state streaming leaves at its first frame (without poses where
``data.pose_dropout`` serves it so). The GRUs' states still start at zero.
"""

from __future__ import annotations

import numpy as np
import torch

from lidarflow.models import uses_ego_motion
from lidarflow.models.recurrent import RecurrentMapModel
from lidarflow.train.data import Windows


@torch.no_grad()
def stream_states(
    model: RecurrentMapModel, maps: np.ndarray, frames: list[int], motions: np.ndarray | None = None
) -> dict[int, np.ndarray]:
    """The head's state (``model``'s last state tensor) before each of ``frames``, as float16
    ``(C, H, W)``, streaming boolean ``maps`` ``(N, 2, H, W)`` (and ``motions`` ``(N, 3)``)."""
    wanted = set(frames)
    out: dict[int, np.ndarray] = {}
    state = model.init_state(1, *maps.shape[-2:], device="cpu", dtype=torch.float32)
    ego = uses_ego_motion(model)
    for t in range(max(wanted, default=-1) + 1):
        if t in wanted:
            out[t] = state[-1][0].numpy().astype(np.float16)
        x = torch.from_numpy(np.ascontiguousarray(maps[t], dtype=np.float32))[None]
        if ego:
            motion = None if motions is None else torch.from_numpy(motions[t])[None]
            _, state = model.step(x, state, motion)  # type: ignore[call-arg]
        else:
            _, state = model.step(x, state)
    return out


def stream_start_states(model: RecurrentMapModel, windows: Windows) -> None:
    """Set ``windows.start_states``: per window, the head's state where streaming its recording
    reaches the window's first frame, with poses and without. ``ValueError`` for a model
    without an occupancy head; ``model`` is left on the CPU in eval mode."""
    if not model.capabilities.occupancy_head:
        raise ValueError("memories_from_stream needs a model with an occupancy head")
    model = model.cpu().eval()
    states: dict[tuple[int, int, bool], np.ndarray] = {}
    for rec, maps in enumerate(windows.maps):
        starts = sorted({start for r, start in windows.index if r == rec})
        if not starts:
            continue
        motions = None if windows.motions is None else windows.motions[rec]
        moving = motions is not None and bool(motions.any())
        posed = stream_states(model, maps, starts, motions) if moving else None
        # Without poses: every window of a model without ego motion, and those pose dropout
        # serves without (a recording that never moves is the same both ways).
        plain = None if moving and not windows.pose_dropout else stream_states(model, maps, starts)
        for start in starts:
            if plain is not None:
                states[(rec, start, False)] = plain[start]
            if motions is not None:
                states[(rec, start, True)] = (posed if posed is not None else plain)[start]
    windows.start_states = states


def split_batch(
    batch: torch.Tensor | list[torch.Tensor] | tuple[torch.Tensor, ...], ego: bool, warm: bool
) -> tuple[torch.Tensor, list[torch.Tensor], torch.Tensor | None]:
    """A training batch -> (maps, [motions] for ego-motion models, start state or None)."""
    parts = list(batch) if (ego or warm) else [batch]
    start = parts.pop() if warm else None
    maps, *motions = parts
    return maps, motions, start  # type: ignore[return-value]


def start_state(
    model: RecurrentMapModel, seq: torch.Tensor, start: torch.Tensor | None
) -> tuple[torch.Tensor, ...] | None:
    """The state to start ``seq`` ``(B, T, C, H, W)`` from: zeros (``None``), or zeros with
    the head's state replaced by ``start`` ``(B, C_head, H, W)``."""
    if start is None:
        return None
    b, _, _, h, w = seq.shape
    zeros = model.init_state(b, h, w, device=seq.device, dtype=seq.dtype)
    return (*zeros[:-1], start.to(device=seq.device, dtype=seq.dtype))
