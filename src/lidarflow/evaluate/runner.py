"""One pass over a recording scores every method: the next map (the main table) and, with a
horizon ``K > 1``, the maps 1..K ahead (:mod:`lidarflow.evaluate.horizon`).

Each method is reset, then sees the frames in turn with what it takes beside them. Its
prediction after frame ``t >= warmup`` is scored against ``O^{t+1}``, its ``backward_flow``
against the true ``B^t``, except across a gap in time (states carry across, as the Predictor's
do); its ``moving`` cells against the simulator's of frame ``t``, gap or not.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from lidarflow.baselines import FrameInputs, Method
from lidarflow.data.blocks import Frames
from lidarflow.data.recording import Recording
from lidarflow.evaluate.horizon import HorizonScore, rolled_forward, scored_frames
from lidarflow.evaluate.resampling import mover_interval
from lidarflow.evaluate.scoring import Scorer
from lidarflow.evaluate.stream import (
    WARMUP,
    RecordingInputs,
    check_length,
    frame_inputs,
    ground_truth_backward_flow,
    ground_truth_moving,
    ground_truth_platform_flow,
    mover_region,
    recording_inputs,
)
from lidarflow.scan import GridSpec

__all__ = [
    "Hooks",
    "Scores",
    "Truth",
    "evaluate_maps",
    "evaluate_recording",
    "horizon_scores",
    "recording_truth",
    "score_stream",
]

#: ``(method, t, probability, backward_flow_or_None)``: a scored prediction of frame ``t + 1``.
OnPrediction = Callable[[str, int, np.ndarray, "np.ndarray | None"], None]
#: ``(method, t, moving, truth_or_None)``: the moving cells a method found in frame ``t``.
OnMoving = Callable[[str, int, np.ndarray, "np.ndarray | None"], None]
#: ``(method, t, predicted)``: the outputs 1..K ahead of frame ``t`` ``(K, H, W)``.
OnAhead = Callable[[str, int, np.ndarray], None]


@dataclass(frozen=True)
class Truth:
    """What a recording knows beyond its maps, each ``t -> array`` or ``None`` where unknown:
    the true ``B^t`` ``(2, H, W)`` (``flow``) and the platform's own (``platform``), the true
    moving cells of ``O^t`` (``moving``), frame ``t``'s dynamic region (``region``)."""

    flow: Callable[[int], np.ndarray] | None = None
    platform: Callable[[int], np.ndarray] | None = None
    moving: Callable[[int], np.ndarray] | None = None
    region: Callable[[int], np.ndarray] | None = None


@dataclass(frozen=True)
class Hooks:
    """What a caller is told during the pass: ``progress(1)`` after every frame;
    ``on_prediction``, ``on_moving`` and ``on_ahead`` with every prediction, moving mask and
    prediction ahead that is scored (copy-last's ahead too)."""

    progress: Callable[[int], None] | None = None
    on_prediction: OnPrediction | None = None
    on_moving: OnMoving | None = None
    on_ahead: OnAhead | None = None


@dataclass(frozen=True)
class Scores:
    """One recording scored: a :class:`Scorer` per method (``next_map``) and, with a horizon,
    ``{metric: {method: [k = 1..K]}}`` over the ``horizon_frames`` frames scored ahead."""

    next_map: dict[str, Scorer]
    horizon: dict[str, dict[str, list[Any]]] | None = None
    horizon_frames: int = 0


def recording_truth(recording: Recording, grid: GridSpec, inputs: RecordingInputs) -> Truth:
    """The simulator's ground truth of ``recording`` on ``grid`` and its dynamic region."""
    return Truth(
        ground_truth_backward_flow(recording, grid),
        ground_truth_platform_flow(recording, grid),
        ground_truth_moving(recording, grid),
        mover_region(recording, grid, inputs),
    )


def score_stream(
    inputs: RecordingInputs,
    methods: Sequence[Method],
    warmup: int = WARMUP,
    horizon: int | None = None,
    truth: Truth = Truth(),
    hooks: Hooks = Hooks(),
) -> Scores:
    """Score ``methods`` on one recording's ``inputs`` in one pass, with a ``horizon`` also
    1..K ahead. Raises :class:`~lidarflow.errors.EvaluateError` when nothing is left to
    score."""
    n = len(inputs.occupancy)
    check_length(n, warmup, inputs.gaps)
    if truth.region is not None:  # asked for frames t + 1 .. t + K in turn
        region = functools.lru_cache(maxsize=(horizon or 1) + 1)(truth.region)
        truth = Truth(truth.flow, truth.platform, truth.moving, region)
    one = _NextMap(inputs, methods, truth, hooks)
    ahead = None if horizon is None else _Ahead(inputs, methods, horizon, warmup, truth, hooks)
    for method in methods:
        method.reset()
    for t in range(n - 1):
        one.start(t, warmup)
        if ahead is not None:
            ahead.copy_last(t)
        for method in methods:
            given = frame_inputs(method, t, inputs)
            probability = method.update(inputs.occupancy[t], inputs.visibility[t], given)
            if t < warmup:
                continue
            one.score(method, t, probability)
            if ahead is not None:
                ahead.score(method, t, probability, given)
        if hooks.progress is not None:
            hooks.progress(1)
    if ahead is None:
        return Scores(one.scorers)
    return Scores(one.scorers, ahead.means(), len(ahead.frames))


class _NextMap:
    """The main table's share of the pass: each method's prediction of the next map."""

    def __init__(
        self, inputs: RecordingInputs, methods: Sequence[Method], truth: Truth, hooks: Hooks
    ) -> None:
        self.occupancy = inputs.occupancy
        self.unscored = {int(g) - 1 for g in inputs.gaps}  # the steps t -> t + 1 across a gap
        self.scorers = {m.name: Scorer() for m in methods}
        self.truth, self.hooks = truth, hooks
        self.threshold = _moving_flow_threshold() if truth.platform is not None else 0.0
        self.inside: np.ndarray | None = None
        self.scored = False

    def start(self, t: int, warmup: int) -> None:
        """Frame ``t`` begins: whether its step is scored, and the next frame's region."""
        self.scored = t >= warmup and t not in self.unscored
        region = self.truth.region
        self.inside = region(t + 1) if self.scored and region is not None else None

    def score(self, method: Method, t: int, probability: np.ndarray) -> None:
        """Score ``method``'s ``probability`` made after frame ``t`` (after the warm-up)."""
        scorer, occupancy = self.scorers[method.name], self.occupancy
        if self.scored:  # the next map and the flow to it: not across a gap
            scorer.add(probability, occupancy[t], occupancy[t + 1])
            if self.inside is not None:
                scorer.add_movers(probability, occupancy[t + 1], self.inside)
            flow = getattr(method, "backward_flow", None)
            if self.hooks.on_prediction is not None:
                self.hooks.on_prediction(method.name, t, probability, flow)
            if self.truth.flow is not None and flow is not None:
                self._score_flow(scorer, t, flow)
        # The moving cells of frame t are scored against frame t's own truth, gap or not.
        # Segmentation costs ~0.6 ms a frame: only ask for it when it is scored or drawn.
        if self.truth.moving is None and self.hooks.on_moving is None:
            return
        moving = getattr(method, "moving", None)
        if moving is None:
            return
        truth = None
        if self.truth.moving is not None:
            truth = self.truth.moving(t) & occupancy[t].astype(bool)
            scorer.add_moving(moving, truth)
        if self.hooks.on_moving is not None:
            self.hooks.on_moving(method.name, t, moving, truth)

    def _score_flow(self, scorer: Scorer, t: int, flow: np.ndarray) -> None:
        assert self.truth.flow is not None
        cells = np.asarray(self.occupancy[t + 1], bool)
        true = self.truth.flow(t)
        error = np.hypot(*(np.asarray(flow, np.float64) - true))
        scorer.add_epe(float(error[cells].sum()), int(cells.sum()))
        if self.truth.platform is not None:
            moving = np.hypot(*(true - self.truth.platform(t))) > self.threshold
            scorer.add_epe_split(error, cells, moving)


def _moving_flow_threshold() -> float:
    from lidarflow.flow_supervision import MOVING_FLOW_THRESHOLD  # torch: only when scored

    return MOVING_FLOW_THRESHOLD


class _Ahead:
    """The horizon tables' share of the pass: copy-last and each method that rolls forward
    (not an ``oracle``), scored 1..K ahead of the frames :func:`scored_frames` names."""

    def __init__(
        self,
        inputs: RecordingInputs,
        methods: Sequence[Method],
        horizon: int,
        warmup: int,
        truth: Truth,
        hooks: Hooks,
    ) -> None:
        self.occupancy, self.visibility = inputs.occupancy, inputs.visibility
        self.frames = set(scored_frames(len(self.occupancy), horizon, warmup, inputs.gaps))
        self.horizon, self.on_ahead = horizon, hooks.on_ahead
        self.shape = tuple(np.shape(self.occupancy[0]))
        self.scores = {"copy_last": HorizonScore(horizon, self.shape, truth.region)}
        self.rolled: set[str] = set()
        for m in methods:
            if m.name not in self.scores and not getattr(m, "oracle", False):
                self.scores[m.name] = HorizonScore(horizon, self.shape, truth.region)
                self.rolled.add(m.name)

    def copy_last(self, t: int) -> None:
        """Score copy-last 1..K ahead of frame ``t``: ``O^t`` at every ``k``."""
        if t in self.frames:
            last = np.broadcast_to(self.occupancy[t], (self.horizon, *self.shape))
            self.scores["copy_last"].add(last, self.occupancy, t)
            if self.on_ahead is not None:
                self.on_ahead("copy_last", t, last)

    def score(self, method: Method, t: int, probability: np.ndarray, given: FrameInputs) -> None:
        """Roll ``method`` forward from frame ``t`` and score it 1..K ahead."""
        if t not in self.frames or method.name not in self.rolled:
            return
        visibility = self.visibility[t]
        predicted = rolled_forward(method, probability, visibility, given, self.horizon)
        self.scores[method.name].add(predicted, self.occupancy, t)
        if self.on_ahead is not None:
            self.on_ahead(method.name, t, predicted)

    def means(self) -> dict[str, dict[str, list[Any]]]:
        """``{metric: {method: [k = 1..K]}}``, copy-last first."""
        out: dict[str, dict[str, list[Any]]] = {}
        for name, score in self.scores.items():
            for key, values in score.means().items():
                out.setdefault(key, {})[name] = values
        copy_last = self.scores["copy_last"]
        if copy_last.region is not None:  # the verdict's margin at K over copy-last, its interval
            out["mover_f1_tolerant_interval"] = {
                name: mover_interval(score.last_mover_rows, copy_last.last_mover_rows)
                for name, score in self.scores.items()
                if name != "copy_last"
            }
        return out


def evaluate_recording(
    recording: Recording,
    methods: Sequence[Method],
    grid: GridSpec | None = None,
    warmup: int = WARMUP,
    progress: Callable[[int], None] | None = None,
    on_prediction: OnPrediction | None = None,
    on_moving: OnMoving | None = None,
) -> dict[str, Scorer]:
    """The main table of :func:`score_stream` on ``recording`` rasterized on ``grid``, with its
    :func:`recording_truth`."""
    grid = grid or GridSpec()
    inputs = recording_inputs(recording, grid, methods)
    truth = recording_truth(recording, grid, inputs)
    hooks = Hooks(progress, on_prediction, on_moving)
    return score_stream(inputs, methods, warmup, None, truth, hooks).next_map


def _maps_inputs(
    occupancy: Frames,
    visibility: Frames,
    motions: np.ndarray | None,
    returns: Sequence[np.ndarray] | None,
    motions_from_poses: bool,
    subcell: Frames | None,
    gaps: Sequence[int],
    paces: Mapping[int, float] | None,
) -> RecordingInputs:
    return RecordingInputs(
        occupancy, visibility, motions, returns, motions_from_poses, subcell,
        [int(g) for g in gaps], dict(paces or {}),
    )  # fmt: skip


def evaluate_maps(
    occupancy: Frames,
    visibility: Frames,
    methods: Sequence[Method],
    warmup: int = WARMUP,
    gt_flow: Callable[[int], np.ndarray] | None = None,
    progress: Callable[[int], None] | None = None,
    on_prediction: OnPrediction | None = None,
    gt_moving: Callable[[int], np.ndarray] | None = None,
    on_moving: OnMoving | None = None,
    motions: np.ndarray | None = None,
    returns: Sequence[np.ndarray] | None = None,
    motions_from_poses: bool = False,
    subcell: Frames | None = None,
    gaps: Sequence[int] = (),
    paces: Mapping[int, float] | None = None,
    gt_platform: Callable[[int], np.ndarray] | None = None,
    region: Callable[[int], np.ndarray] | None = None,
) -> dict[str, Scorer]:
    """The main table of :func:`score_stream` on maps ``(N, H, W)`` and the rest of a
    :class:`~lidarflow.evaluate.stream.RecordingInputs`, with the :class:`Truth` ``gt_flow``,
    ``gt_platform``, ``gt_moving`` and ``region``."""
    inputs = _maps_inputs(
        occupancy, visibility, motions, returns, motions_from_poses, subcell, gaps, paces
    )
    truth = Truth(gt_flow, gt_platform, gt_moving, region)
    hooks = Hooks(progress, on_prediction, on_moving)
    return score_stream(inputs, methods, warmup, None, truth, hooks).next_map


def horizon_scores(
    occupancy: Frames,
    visibility: Frames,
    methods: Sequence[Method],
    horizon: int,
    warmup: int = WARMUP,
    progress: Callable[[int], None] | None = None,
    motions: np.ndarray | None = None,
    returns: Sequence[np.ndarray] | None = None,
    motions_from_poses: bool = False,
    subcell: Frames | None = None,
    gaps: Sequence[int] = (),
    paces: Mapping[int, float] | None = None,
    region: Callable[[int], np.ndarray] | None = None,
    on_ahead: OnAhead | None = None,
) -> dict[str, dict[str, list[Any]]]:
    """The horizon tables of :func:`score_stream` on maps ``(N, H, W)`` (the other inputs as
    :func:`evaluate_maps`'): ``{metric: {method: [k = 1..K]}}``, copy-last first. Raises
    :class:`~lidarflow.errors.EvaluateError` where no frame has ``horizon`` frames after it
    without a gap."""
    scored_frames(len(occupancy), horizon, warmup, gaps)  # the horizon's refusal first
    inputs = _maps_inputs(
        occupancy, visibility, motions, returns, motions_from_poses, subcell, gaps, paces
    )
    hooks = Hooks(progress, on_ahead=on_ahead)
    scores = score_stream(inputs, methods, warmup, horizon, Truth(region=region), hooks)
    assert scores.horizon is not None
    return scores.horizon
