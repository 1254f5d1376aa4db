"""Run predictors over recordings in streaming order and score them (design notes §5).

Each method sees the frames one at a time, its state carried from frame to frame. The
prediction made after frame ``t`` is scored against frame ``t + 1`` for ``t >= warmup``: the
first ``warmup`` frames only warm the state up.

Where a recording's scans stop for a while (a gap, :func:`lidarflow.data.gaps.frames_after_gaps`)
the step across the gap is not scored: the frame after it is not the next scan. Every method's
state carries across, as the :class:`~lidarflow.predict.Predictor`'s does: measured on the
development recordings with gaps cut in (0.3 s to 13 s), the bundled model predicted the
frames after a gap better carrying its state than restarting over all but the first ten (about
even there; restarting better on the moving recordings and after moving to another place:
``docs/research/gaps/``).

A method that exposes ``moving`` (``(H, W)`` bool after ``update``: the cells of the frame just
given that move on their own) is also scored for moving-object segmentation against the
simulator's ``moving`` ground truth of that frame, where the recording has it.

The flow's end-point error is also split into the cells that truly move on their own and the
rest (``epe_moving`` / ``epe_static``): a cell of ``O^{t+1}`` moves when its true ``B^t``
differs from the platform's own backward flow (from the simulator's true poses; zero without
poses) by more than :data:`lidarflow.flow_supervision.MOVING_FLOW_THRESHOLD` cells, the rule
the supervised flow loss weights by.

Ego motion: methods with ``uses_motion`` (ego-motion models, :class:`~lidarflow.evaluate.ego.
CopyLastEgo`) also get the sensor's motion per frame from the recording's poses (see
:mod:`lidarflow.evaluate.ego`). On a recording without poses, models built with
``poses_optional`` get the motion matched from its scans (NaN steps: none counted, not
compensated); any other is refused with :class:`EvaluateError` rather than evaluated
uncompensated.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from lidarflow.data.blocks import Frames, streamed_maps, streamed_subcell
from lidarflow.data.gaps import frames_after_gaps
from lidarflow.data.recording import Recording
from lidarflow.errors import EvaluateError
from lidarflow.evaluate.dynamic import recording_region
from lidarflow.evaluate.ego import recording_motions
from lidarflow.evaluate.scoring import Scorer
from lidarflow.motion.icp import streamed_points
from lidarflow.motion.pacing import paces_after_long_steps
from lidarflow.predict.baselines import Method
from lidarflow.scan import GridSpec
from lidarflow.sim.storage import dense_flow

__all__ = [
    "WARMUP",
    "RecordingInputs",
    "check_length",
    "evaluate_maps",
    "evaluate_recording",
    "ground_truth_backward_flow",
    "ground_truth_moving",
    "ground_truth_platform_flow",
    "has_ground_truth",
    "method_inputs",
    "mover_region",
    "other_recorded_grid",
    "recording_inputs",
]

WARMUP = 10


def _made_on(recording: Recording, grid: GridSpec) -> bool:
    stored = recording.meta.get("grid") or {}
    return (stored.get("height"), stored.get("width"), stored.get("res")) == (
        grid.height,
        grid.width,
        grid.res,
    )


def other_recorded_grid(recording: Recording, grid: GridSpec) -> dict[str, Any] | None:
    """The grid recorded with ``recording`` (``convert``/``simulate``'s ``meta["grid"]``) where
    it is not ``grid``, else ``None``: scored on ``grid``, such a recording's ground truth
    (made on its own grid) is not scored, which the report should say."""
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
    if not any(k in recording.extras for k in _FLOW_EXTRAS):
        return None
    if not _made_on(recording, grid):
        return None
    return lambda t: dense_flow(recording, t)[0]


def ground_truth_moving(recording: Recording, grid: GridSpec) -> Callable[[int], np.ndarray] | None:
    """``t -> `` the simulator's moving cells of ``O^t`` ``(H, W)`` bool, or ``None`` when the
    recording has none or it was made on another grid than ``grid``."""
    moving = recording.extras.get("moving")
    if moving is None or not _made_on(recording, grid) or moving.shape[1:] != grid.shape:
        return None
    return lambda t: np.asarray(moving[t], bool)


def check_length(
    frames: int, warmup: int = WARMUP, gaps: Sequence[int] = (), name: str = "the recording"
) -> None:
    """Raise :class:`EvaluateError` naming ``name`` when a recording of ``frames`` frames (with
    ``gaps``, the frames after a gap in time) leaves no step to score after ``warmup``; the
    command line checks every recording with it before the long work on any of them."""
    unscored = {int(g) - 1 for g in gaps}  # the steps t -> t + 1 across a gap
    if frames < warmup + 2 or all(t in unscored for t in range(warmup, frames - 1)):
        has = f"{frames} frame{'s' * (frames != 1)}"
        gapped = f" and {len(unscored)} gaps" if unscored else ""
        raise EvaluateError(
            f"{name}: too short to evaluate: needs at least {warmup + 2} frames ({warmup} to "
            "warm up, then a prediction and its target not across a gap in time), it has "
            f"{has}{gapped}; lower --warmup or leave it out"
        )


def evaluate_maps(
    occupancy: Frames,
    visibility: Frames,
    methods: Sequence[Method],
    warmup: int = WARMUP,
    gt_flow: Callable[[int], np.ndarray] | None = None,
    progress: Callable[[int], None] | None = None,
    on_prediction: Callable[[str, int, np.ndarray, np.ndarray | None], None] | None = None,
    gt_moving: Callable[[int], np.ndarray] | None = None,
    on_moving: Callable[[str, int, np.ndarray, np.ndarray | None], None] | None = None,
    motions: np.ndarray | None = None,
    returns: Sequence[np.ndarray] | None = None,
    motions_from_poses: bool = False,
    subcell: Frames | None = None,
    gaps: Sequence[int] = (),
    paces: Mapping[int, float] | None = None,
    gt_platform: Callable[[int], np.ndarray] | None = None,
    region: Callable[[int], np.ndarray] | None = None,
) -> dict[str, Scorer]:
    """Score every method on one recording's maps ``(N, H, W)``.

    ``gaps``: the frames that follow a gap in time; the step into each is not scored (the next
    map, the flow to it; every method still sees every frame, and the moving cells of every
    frame are scored). ``paces`` (:func:`lidarflow.motion.pacing.paces_after_long_steps`): after a
    long step forwards in time (a gap, scans dropped), methods with ``uses_motion`` also get
    ``pace``, the typical step over that one, to scale their guess of the motion to the next
    frame (the last one spans the long step).

    ``motions`` ``(N, 3)`` (cells; frame ``t`` in frame ``t - 1``) go to the methods with
    ``uses_motion``: ``update(occ, vis, motion=motions[t], next_motion=motions[t + 1])``.
    Methods with ``takes_returns`` also get each frame's scan returns (``returns[t]``, see
    :func:`lidarflow.motion.icp.scan_points`) and whether the motions came from poses
    (``motions_from_poses``), to take the scans' own motion where the poses disagree with the
    scans; by default the motions are only checked (as ones found from the scans are).

    Methods with ``takes_subcell`` (models built with ``subcell_input``) also get ``subcell[t]``
    ``(2, H, W)``, where the frame's returns lie inside their cells
    (:meth:`~lidarflow.data.Recording.subcell_maps`).

    ``on_prediction(method_name, t, probability, backward_flow_or_None)`` is called for every
    scored prediction (the map predicted for frame ``t + 1``), e.g. to draw overlays.

    A method that exposes ``backward_flow`` (``(2, H, W)`` cells, after ``update``) is also
    scored for end-point error against ``gt_flow(t)`` (``B^t``) on the cells occupied in the
    next frame; with ``gt_platform(t)`` (the platform's own ``B^t``, see the module docstring)
    also on the moving and the static ones of those cells apart.

    A method that exposes ``moving`` is scored (IoU of the moving class) against
    ``gt_moving(t)`` on the cells occupied in frame ``t``; ``on_moving(method_name, t, moving,
    truth_or_None)`` is called with every such mask, e.g. to draw it.

    With ``region`` (``t ->`` frame ``t``'s dynamic region, :mod:`lidarflow.evaluate.dynamic`)
    every scored prediction is also scored inside its target frame's region (the mover metric).
    """
    n = len(occupancy)
    check_length(n, warmup, gaps)
    unscored = {int(g) - 1 for g in gaps}  # the steps t -> t + 1 across a gap
    scorers = {m.name: Scorer() for m in methods}
    threshold = _moving_flow_threshold() if gt_platform is not None else 0.0
    for m in methods:
        m.reset()
    for t in range(n - 1):
        inside = None if region is None or t < warmup or t in unscored else region(t + 1)
        for m in methods:
            extra = method_inputs(m, t, motions, returns, motions_from_poses, subcell, paces)
            probability = m.update(occupancy[t], visibility[t], **extra)  # type: ignore[call-arg]
            if t < warmup:
                continue
            if t not in unscored:  # the next map and the flow to it: not across a gap
                scorers[m.name].add(probability, occupancy[t], occupancy[t + 1])
                if inside is not None:
                    scorers[m.name].add_movers(probability, occupancy[t + 1], inside)
                flow = getattr(m, "backward_flow", None)
                if on_prediction is not None:
                    on_prediction(m.name, t, probability, flow)
                if gt_flow is not None and flow is not None:
                    cells = np.asarray(occupancy[t + 1], bool)
                    truth = gt_flow(t)
                    error = np.hypot(*(np.asarray(flow, np.float64) - truth))
                    scorers[m.name].add_epe(float(error[cells].sum()), int(cells.sum()))
                    if gt_platform is not None:
                        moving = np.hypot(*(truth - gt_platform(t))) > threshold
                        scorers[m.name].add_epe_split(error, cells, moving)
            # The moving cells of frame t are scored against frame t's own truth, gap or not.
            # Segmentation costs ~0.6 ms a frame: only ask for it when it is scored or drawn.
            wanted = gt_moving is not None or on_moving is not None
            moving = getattr(m, "moving", None) if wanted else None
            if moving is not None:
                truth = None if gt_moving is None else gt_moving(t) & occupancy[t].astype(bool)
                if truth is not None:
                    scorers[m.name].add_moving(moving, truth)
                if on_moving is not None:
                    on_moving(m.name, t, moving, truth)
        if progress is not None:
            progress(1)
    return scorers


def _moving_flow_threshold() -> float:
    from lidarflow.flow_supervision import MOVING_FLOW_THRESHOLD  # torch: only when scored

    return MOVING_FLOW_THRESHOLD


def method_inputs(
    method: Method,
    t: int,
    motions: np.ndarray | None,
    returns: Sequence[np.ndarray] | None,
    motions_from_poses: bool,
    subcell: Frames | None,
    paces: Mapping[int, float] | None = None,
) -> dict[str, object]:
    """What ``method.update`` takes for frame ``t`` beside the maps."""
    extra: dict[str, object] = {}
    if motions is not None and method.takes.motion:
        # NaN: no motion known for that step (scan matching found none): not compensated
        motion, following = (None if np.isnan(v).any() else v for v in motions[t : t + 2])
        extra = {"motion": motion, "next_motion": following}
        if paces and t in paces:
            extra["pace"] = paces[t]
        if method.takes.returns:
            extra["returns"] = None if returns is None else returns[t]
            extra["from_pose"] = motions_from_poses
    if subcell is not None and method.takes.subcell:
        extra["subcell"] = subcell[t]
    return extra


def ground_truth_platform_flow(
    recording: Recording, grid: GridSpec
) -> Callable[[int], np.ndarray] | None:
    """``t -> `` the backward flow ``(2, H, W)`` a static world would have from frame ``t + 1``
    to ``t``, from the true poses (``extras["true_poses"]``, else the poses; zero without
    any), where the recording has ground-truth flow on ``grid``; else ``None``."""
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
    """What a streamed evaluation feeds its methods from one recording, in blocks of frames
    (:mod:`lidarflow.data.blocks`): maps, ego motions, returns, sub-cell maps and gaps."""

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
    """The inputs ``methods`` (baselines, :class:`~lidarflow.evaluate.model_method.ModelMethod`
    ...) need from ``recording`` on ``grid``; what none of them asks for is ``None``."""
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


def evaluate_recording(
    recording: Recording,
    methods: Sequence[Method],
    grid: GridSpec | None = None,
    warmup: int = WARMUP,
    progress: Callable[[int], None] | None = None,
    on_prediction: Callable[[str, int, np.ndarray, np.ndarray | None], None] | None = None,
    on_moving: Callable[[str, int, np.ndarray, np.ndarray | None], None] | None = None,
) -> dict[str, Scorer]:
    """Rasterize ``recording`` on ``grid`` and score every method on it (with the
    simulator's ground truth flow and moving cells where it has them), not across its gaps,
    and inside its dynamic region (:func:`mover_region`)."""
    grid = grid or GridSpec()
    inputs = recording_inputs(recording, grid, methods)
    region = mover_region(recording, grid, inputs)
    return evaluate_maps(
        inputs.occupancy,
        inputs.visibility,
        methods,
        warmup,
        ground_truth_backward_flow(recording, grid),
        progress,
        on_prediction,
        ground_truth_moving(recording, grid),
        on_moving,
        inputs.motions,
        inputs.returns,
        inputs.motions_from_poses,
        inputs.subcell,
        inputs.gaps,
        inputs.paces,
        ground_truth_platform_flow(recording, grid),
        region,
    )


def mover_region(
    recording: Recording, grid: GridSpec, inputs: RecordingInputs
) -> Callable[[int], np.ndarray]:
    """``t -> `` the dynamic region of frame ``t`` where the mover metric scores
    (:func:`lidarflow.evaluate.dynamic.recording_region`): the simulator's true moving cells
    where the recording has them on ``grid``, else the cells rarely occupied."""
    return recording_region(
        recording,
        grid,
        inputs.occupancy,
        inputs.visibility,
        ground_truth_moving(recording, grid),
    )
