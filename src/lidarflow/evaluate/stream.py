"""What a streamed evaluation feeds its methods from a recording and scores them against: the
maps in blocks of frames (:class:`RecordingInputs`), what each method takes beside them per
frame (:func:`frame_inputs`), and the simulator's ground truth where there is one (a cell moves
on its own where its true flow differs from the platform's by more than
:data:`~lidarflow.flow_supervision.MOVING_FLOW_THRESHOLD` cells, as in the flow loss).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from lidarflow.baselines import FrameInputs, Method
from lidarflow.data.blocks import Frames, streamed_maps, streamed_subcell
from lidarflow.data.gaps import frames_after_gaps
from lidarflow.data.recording import Recording
from lidarflow.errors import EvaluateError
from lidarflow.evaluate.dynamic import recording_region
from lidarflow.evaluate.ego import recording_motions
from lidarflow.motion.icp import streamed_points
from lidarflow.motion.pacing import paces_after_long_steps
from lidarflow.scan import GridSpec
from lidarflow.sim.storage import dense_flow

__all__ = [
    "WARMUP",
    "RecordingInputs",
    "check_length",
    "frame_inputs",
    "ground_truth_backward_flow",
    "ground_truth_moving",
    "ground_truth_platform_flow",
    "has_ground_truth",
    "mover_region",
    "other_recorded_grid",
    "recording_inputs",
]

WARMUP = 10


def _made_on(recording: Recording, grid: GridSpec) -> bool:
    stored = recording.meta.get("grid") or {}
    made = (stored.get("height"), stored.get("width"), stored.get("res"))
    return made == (grid.height, grid.width, grid.res)


def other_recorded_grid(recording: Recording, grid: GridSpec) -> dict[str, Any] | None:
    """The grid recorded with ``recording`` (``meta["grid"]``) where it is not ``grid``, else
    ``None``."""
    recorded = recording.meta.get("grid")
    return None if not recorded or _made_on(recording, grid) else dict(recorded)


#: The simulator's ground-truth flow, dense or per occupied cell (lidarflow.sim.storage).
_FLOW_EXTRAS = ("flow_backward", "flow_backward_cells")


def has_ground_truth(recording: Recording) -> bool:
    """Whether ``recording`` holds the simulator's ground truth (flow or moving cells)."""
    return any(k in recording.extras for k in (*_FLOW_EXTRAS, "moving"))


def ground_truth_backward_flow(
    recording: Recording, grid: GridSpec
) -> Callable[[int], np.ndarray] | None:
    """``t -> B^t`` ``(2, H, W)`` from the simulator's ground truth, or ``None`` when the
    recording has none or it was made on another grid than ``grid``."""
    if not any(k in recording.extras for k in _FLOW_EXTRAS) or not _made_on(recording, grid):
        return None
    return lambda t: dense_flow(recording, t)[0]


def ground_truth_moving(recording: Recording, grid: GridSpec) -> Callable[[int], np.ndarray] | None:
    """``t -> `` the simulator's moving cells of ``O^t`` ``(H, W)`` bool, or ``None`` as
    :func:`ground_truth_backward_flow`."""
    moving = recording.extras.get("moving")
    if moving is None or not _made_on(recording, grid) or moving.shape[1:] != grid.shape:
        return None
    return lambda t: np.asarray(moving[t], bool)


def check_length(
    frames: int, warmup: int = WARMUP, gaps: Sequence[int] = (), name: str = "the recording"
) -> None:
    """Raise :class:`EvaluateError` naming ``name`` when a recording of ``frames`` frames (with
    ``gaps``, the frames after a gap in time) leaves no step to score after ``warmup``."""
    unscored = {int(g) - 1 for g in gaps}  # the steps t -> t + 1 across a gap
    if frames < warmup + 2 or all(t in unscored for t in range(warmup, frames - 1)):
        has = f"{frames} frame{'s' * (frames != 1)}"
        gapped = f" and {len(unscored)} gaps" if unscored else ""
        raise EvaluateError(
            f"{name}: too short to evaluate: needs at least {warmup + 2} frames ({warmup} to "
            "warm up, then a prediction and its target not across a gap in time), it has "
            f"{has}{gapped}; lower --warmup or leave it out"
        )


def frame_inputs(method: Method, t: int, inputs: RecordingInputs) -> FrameInputs:
    """What ``method`` is given with frame ``t``'s maps: of ``inputs``, what it ``takes``."""
    motion = following = pace = returns = subcell = None
    from_pose = True
    if inputs.motions is not None and method.takes.motion:
        # NaN: no motion known for that step (scan matching found none): not compensated
        motion, following = (None if np.isnan(v).any() else v for v in inputs.motions[t : t + 2])
        pace = inputs.paces.get(t)
        if method.takes.returns:
            returns = None if inputs.returns is None else inputs.returns[t]
            from_pose = inputs.motions_from_poses
    if inputs.subcell is not None and method.takes.subcell:
        subcell = inputs.subcell[t]
    return FrameInputs(motion, following, pace, returns, from_pose, subcell)


def ground_truth_platform_flow(
    recording: Recording, grid: GridSpec
) -> Callable[[int], np.ndarray] | None:
    """``t -> `` the backward flow ``(2, H, W)`` a static world would have from frame ``t + 1``
    to ``t``, by the true poses (else the poses; zero without any), where the recording has
    ground-truth flow on ``grid``; else ``None``."""
    if ground_truth_backward_flow(recording, grid) is None:
        return None
    import torch

    from lidarflow.flow_supervision import platform_flows
    from lidarflow.motion.odometry import metres_to_cells, relative_motions

    poses = recording.extras.get("true_poses", recording.poses)
    if poses is None:
        zero = np.zeros((2, *grid.shape))
        return lambda t: zero
    motions = metres_to_cells(relative_motions(np.asarray(poses), len(recording))[0], grid.res)

    def platform(t: int) -> np.ndarray:
        motion = torch.from_numpy(motions[t + 1 : t + 2].astype(np.float64))
        return platform_flows(motion, grid.height, grid.width)[0, :2].numpy()

    return platform


@dataclass(frozen=True)
class RecordingInputs:
    """What a streamed evaluation feeds its methods from one recording, in blocks of frames."""

    occupancy: Frames
    visibility: Frames
    motions: np.ndarray | None  # (N, 3) cells, radians; NaN unknown; None: no method wants them
    returns: Sequence[np.ndarray] | None  # each frame's returns, where odometry may be replaced
    motions_from_poses: bool  # the motions are odometry (else matched from the scans)
    subcell: Frames | None
    gaps: list[int]
    paces: dict[int, float]  # frames after a long step (a gap, scans dropped): typical / step


def recording_inputs(
    recording: Recording, grid: GridSpec, methods: Sequence[Method]
) -> RecordingInputs:
    """The inputs ``methods`` need from ``recording`` on ``grid``; what none asks for is
    ``None``."""
    # a block of frames at a time: a long recording's maps held whole take gigabytes
    occupancy, visibility = streamed_maps(recording, grid)
    motions = recording_motions(recording, grid, methods, occupancy)
    # The returns matter only where the motions are odometry that a model may replace; without
    # poses the motions already came from the scans (recording_motions) and are only checked.
    takes_returns = (
        recording.has_poses and motions is not None and any(m.takes.returns for m in methods)
    )
    takes_subcell = any(m.takes.subcell for m in methods)
    return RecordingInputs(
        occupancy,
        visibility,
        motions,
        streamed_points(recording) if takes_returns else None,
        recording.has_poses,
        streamed_subcell(recording, grid) if takes_subcell else None,
        frames_after_gaps(recording.stamps_ns),
        paces_after_long_steps(recording.stamps_ns),
    )


def mover_region(
    recording: Recording, grid: GridSpec, inputs: RecordingInputs
) -> Callable[[int], np.ndarray]:
    """``t -> `` frame ``t``'s dynamic region (:func:`~lidarflow.evaluate.dynamic.
    recording_region`), from the simulator's moving cells where it has them on ``grid``."""
    moving = ground_truth_moving(recording, grid)
    return recording_region(recording, grid, inputs.occupancy, inputs.visibility, moving)
