"""F1 per prediction horizon: how well a model predicts 1..K frames ahead.

Each model streams as in :mod:`lidarflow.evaluate.stream` (the same
:class:`~lidarflow.evaluate.model_method.ModelMethod`, fed the same inputs, one step per frame,
state carried). After frame ``t`` (``t >= warmup``) it also rolls forward ``K - 1`` more steps
from a copy of its state (:meth:`lidarflow.predict.engine.Engine.roll`, what
:class:`lidarflow.predict.Predictor` does for ``horizon=K``), and the prediction ``k`` steps
ahead is scored (F1 at 0.4, and changed-cell F1: the cells of ``O^{t+k}`` that differ from
``O^t``) against ``O^{t+k}``. Copy-last's ``k``-step prediction is ``O^t``; the other baselines
roll forward as the models do, their decided prediction fed back to a copy of their state:
constant velocity shifts the last map ``k`` times, the last map moved by the ego motion
(``copy_last_ego``) moves on by the same motion each step, the temporal average takes its own
prediction into its window. A method with ``ahead(K)`` predicts 1..K ahead itself, nothing fed
back: the tracker (:mod:`lidarflow.predict.tracker`) moves each object by ``k`` times its
velocity and leaves the background where it is.
Beside F1 the peers' metrics (:mod:`lidarflow.evaluate.peer_metrics`) are averaged per ``k``
over the same frames: the WMSE and SSIM of what each method outputs ``k`` ahead (the decided
probability a model's roll-out thresholds, a baseline's own output, copy-last's ``O^t``) against
``O^{t+k}``. They cost ~8 ms a frame and method at ``K = 10`` on a busy 2-core CPU (SSIM of
the ten maps ~7 ms), for five methods about a tenth of the ~300 ms a frame their roll-outs took
on the sample bag (runs with and without them were within the noise between runs).
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

The mover metric (:mod:`lidarflow.evaluate.movers`) is scored per ``k`` too, inside the
dynamic region of the target frame ``t + k`` (:func:`lidarflow.evaluate.stream.mover_region`):
exact and tolerant F1 of the decided map, AUC and soft IoU of the output.
"""

from __future__ import annotations

import contextlib
import copy
import functools
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from lidarflow.data.blocks import Frames
from lidarflow.errors import EvaluateError
from lidarflow.evaluate.metrics import THRESHOLD, Counts, confusion
from lidarflow.evaluate.model_method import ModelMethod
from lidarflow.evaluate.movers import MoverScore
from lidarflow.evaluate.peer_metrics import SSIM_WINDOW, ssim, wmse
from lidarflow.evaluate.report import add_horizon_verdict, count_recordings_won
from lidarflow.evaluate.stream import method_inputs, mover_region, recording_inputs
from lidarflow.predict.baselines import Method
from lidarflow.scan import GridSpec

__all__ = [
    "add_horizon_entry",
    "add_horizon_scores",
    "check_horizon",
    "horizon_scores",
    "recording_horizon",
    "scored_frames",
]


def check_horizon(frames: int, horizon: int, warmup: int = 10, name: str = "the recording") -> None:
    """Refuse, before any work, a ``horizon`` that a recording of ``frames`` frames cannot use:
    no frame after the ``warmup`` has a frame ``horizon`` ahead of it. ``evaluate`` checks its
    recordings with it (:func:`scored_frames`), ``predict`` and ``live`` theirs with no
    warm-up (they predict from the first scan): a roll-out of a huge horizon per scan would
    otherwise run for hours, to predict frames that are not there."""
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
    """The frames ``t`` (in order) whose predictions 1..``horizon`` ahead are scored on a
    recording of ``frames`` frames with ``gaps`` (the frames after a gap in time). Raises
    :class:`EvaluateError` naming ``name`` when there are none; the command line checks every
    recording with it before the long work on any of them."""
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


def add_horizon_scores(
    report: dict[str, Any],
    named: Sequence[tuple[str, Any]],
    methods: Sequence[Method],
    spec: GridSpec,
    warmup: int,
    horizon: int,
    bar: Callable[[int, str], Any] | None = None,
    on_ahead: Callable[[str, str, int, np.ndarray], None] | None = None,
) -> None:
    """:func:`horizon_scores` of every recording of ``named`` (``(name, Recording)``) into its
    entry of ``report`` (what ``evaluate_and_report`` returned for them) as ``horizon_f1``,
    ``horizon_changed_f1``, ``horizon_wmse``, ``horizon_ssim``, ``horizon_mover_f1``,
    ``horizon_mover_f1_tolerant``, ``horizon_mover_auc``, ``horizon_mover_soft_iou`` (with
    ``horizon_undefined: ["mover_f1"]`` where no true cell lay in the region ``K`` ahead),
    and extends the recording's verdicts by the movers at ``K``
    (:func:`~lidarflow.evaluate.report.add_horizon_verdict`). Every model and baseline rolls
    forward; what knows the future (``oracle``) has no roll-out of its own. ``bar(total, name)``:
    a progress bar (a context manager with ``update``) per recording. ``on_ahead(recording,
    method, t, predicted)``: each scored prediction 1..K ahead of frame ``t``, as
    :func:`horizon_scores` passes it."""
    for entry, (name, recording) in zip(report["recordings"], named, strict=True):
        progress = None if bar is None else functools.partial(_bar_of, bar, name)
        scored = recording_horizon(
            name, recording, methods, spec, warmup, horizon, progress, on_ahead
        )
        add_horizon_entry(entry, scored)
    count_recordings_won(report)


def _bar_of(bar: Callable[[int, str], Any], name: str, total: int) -> Any:
    return bar(total, name)


def recording_horizon(
    name: str,
    recording: Any,
    methods: Sequence[Method],
    spec: GridSpec,
    warmup: int,
    horizon: int,
    bar: Callable[[int], Any] | None = None,
    on_ahead: Callable[[str, str, int, np.ndarray], None] | None = None,
) -> dict[str, Any]:
    """One recording's share of :func:`add_horizon_scores`: the ``horizon_*`` keys of its
    report entry (and ``horizon_undefined``), for :func:`add_horizon_entry`. ``bar(total)``: a
    progress bar (a context manager with ``update``). ``evaluate --jobs`` runs it in a worker
    process per recording."""
    streamed = [m for m in methods if not getattr(m, "oracle", False)]
    inputs = recording_inputs(recording, spec, streamed)
    region = mover_region(recording, spec, inputs)
    total = len(streamed) * max(0, len(inputs.occupancy) - horizon)
    with bar(total) if bar is not None else contextlib.nullcontext() as progress:
        scores = horizon_scores(
            inputs.occupancy, inputs.visibility, streamed, horizon, warmup,
            None if progress is None else progress.update,
            inputs.motions, inputs.returns, inputs.motions_from_poses, inputs.subcell,
            inputs.gaps, inputs.paces, region,
            None if on_ahead is None else functools.partial(on_ahead, name),
        )  # fmt: skip
    true_cells = scores.pop("mover_true_cells")
    # f1, changed_f1, wmse, ssim (none on a tiny grid)
    keys: dict[str, Any] = {f"horizon_{key}": scored for key, scored in scores.items()}
    if not true_cells["copy_last"][-1]:
        keys["horizon_undefined"] = ["mover_f1"]
    return keys


def add_horizon_entry(entry: dict[str, Any], scored: dict[str, Any]) -> None:
    """Put a recording's :func:`recording_horizon` into its report ``entry`` and extend its
    verdicts by the movers at ``K`` (:func:`~lidarflow.evaluate.report.add_horizon_verdict`);
    the report's counts of recordings won follow from :func:`count_recordings_won` after."""
    entry.update(scored)
    add_horizon_verdict(entry)


def horizon_scores(
    occupancy: Frames,
    visibility: Frames,
    methods: Sequence[Method],
    horizon: int,
    warmup: int = 10,
    progress: Callable[[int], None] | None = None,
    motions: np.ndarray | None = None,
    returns: Sequence[np.ndarray] | None = None,
    motions_from_poses: bool = False,
    subcell: Frames | None = None,
    gaps: Sequence[int] = (),
    paces: Mapping[int, float] | None = None,
    region: Callable[[int], np.ndarray] | None = None,
    on_ahead: Callable[[str, int, np.ndarray], None] | None = None,
) -> dict[str, dict[str, list[Any]]]:
    """``{"f1": {name: [k = 1..K]}, "changed_f1": {...}, "wmse": {...}, "ssim": {...}}`` on
    maps ``(N, H, W)``: copy-last (always, first) and each method, models and baselines alike
    (see the module's docstring); changed-cell F1 ``k`` ahead scores the cells of ``O^{t+k}``
    that differ from ``O^t``; ``wmse`` and ``ssim`` are means over the scored frames (no
    ``ssim`` on a grid under 11 x 11 cells).

    ``progress(1)`` is called after every method step on a recorded frame. The other inputs are
    :func:`~lidarflow.evaluate.stream.evaluate_maps`' (the motions, returns, sub-cell maps and
    paces each method takes); ``gaps``: the frames that follow a gap in time (no roll-out
    across one is scored; states carry on). With ``region`` (``t ->`` frame ``t``'s dynamic
    region) also ``mover_f1``, ``mover_f1_tolerant``, ``mover_auc`` (``None`` where the
    region held one class only), ``mover_soft_iou`` and ``mover_true_cells`` (the true cells
    in the regions ``k`` ahead, alike for every method). ``on_ahead(method, t, predicted)`` is
    called with every scored prediction, ``predicted`` ``(K, H, W)`` the output 1..K ahead of
    frame ``t`` (copy-last's too): what a caller scores beside these (annotated people)."""
    n = len(occupancy)
    scored = scored_frames(n, horizon, warmup, gaps)
    scoring = set(scored)
    shape = np.shape(occupancy[0])
    if region is not None:  # each method asks for the regions of t + 1 .. t + K in turn
        region = functools.lru_cache(maxsize=horizon + 1)(region)
    copy = _Ahead(horizon, shape, region)
    for t in scored:
        copy.add(np.broadcast_to(occupancy[t], (horizon, *shape)), occupancy, t)
        if on_ahead is not None:
            on_ahead("copy_last", t, np.broadcast_to(occupancy[t], (horizon, *shape)))
    scores = {name: {"copy_last": value} for name, value in copy.means().items()}
    for method in methods:
        if method.name in scores["f1"]:  # copy-last is scored above, by its definition
            continue
        ahead = _Ahead(horizon, shape, region)
        method.reset()
        for t in range(n - horizon):
            extra = method_inputs(method, t, motions, returns, motions_from_poses, subcell, paces)
            prediction = method.update(occupancy[t], visibility[t], **extra)  # type: ignore[arg-type]
            if progress is not None:
                progress(1)
            if t not in scoring:
                continue
            predicted = np.stack(_ahead(method, prediction, visibility[t], extra, horizon))
            ahead.add(predicted, occupancy, t)
            if on_ahead is not None:
                on_ahead(method.name, t, predicted)
        for name, value in ahead.means().items():
            scores[name][method.name] = value
    return scores


class _Ahead:
    """Sums per step ``k`` over the scored frames: F1 and changed-cell F1 counts, WMSE, SSIM,
    and the mover metric where there is a ``region``."""

    def __init__(
        self,
        horizon: int,
        shape: tuple[int, ...],
        region: Callable[[int], np.ndarray] | None = None,
    ) -> None:
        self.counts, self.changed = _counts(horizon), _counts(horizon)
        self.region = region
        self.movers = [MoverScore() for _ in range(horizon)]
        self.wmse = np.zeros(horizon)
        self.ssim = np.zeros(horizon) if min(shape) >= SSIM_WINDOW else None
        self.frames = 0

    def add(self, predicted: np.ndarray, occupancy: Frames, t: int) -> None:
        """``predicted`` ``(K, H, W)``: the outputs 1..K ahead of frame ``t``."""
        truths = np.stack([occupancy[t + 1 + k] for k in range(len(predicted))])
        for k, (decided, truth) in enumerate(zip(predicted, truths, strict=True)):
            self.counts[k] = self.counts[k] + confusion(decided >= THRESHOLD, truth)
            self.changed[k] = self.changed[k] + confusion(
                decided >= THRESHOLD, truth, _changed(occupancy[t], truth)
            )
            if self.region is not None:
                self.movers[k].add(decided, truth, self.region(t + 1 + k))
        self.wmse += wmse(predicted, truths)
        if self.ssim is not None:
            self.ssim += ssim(predicted, truths)
        self.frames += 1

    def means(self) -> dict[str, list[Any]]:
        out: dict[str, list[Any]] = {"f1": _f1(self.counts), "changed_f1": _f1(self.changed)}
        out["wmse"] = [float(v) for v in self.wmse / max(self.frames, 1)]
        if self.ssim is not None:
            out["ssim"] = [float(v) for v in self.ssim / max(self.frames, 1)]
        if self.region is not None:
            summaries = [m.summary() for m in self.movers]
            for key in ("f1", "f1_tolerant", "auc", "soft_iou", "true_cells"):
                out[f"mover_{key}"] = [s[key] for s in summaries]
        return out


def _ahead(
    method: Method,
    prediction: np.ndarray,
    visibility: np.ndarray,
    extra: dict[str, object],
    horizon: int,
) -> list[np.ndarray]:
    """``method``'s predictions 1..``horizon`` frames ahead of the frame it was just given: a
    model's roll-out (:meth:`lidarflow.predict.engine.Engine.roll`), a method's own
    ``ahead(horizon)`` where it has one (the tracker), another baseline's by feeding its
    decided prediction back to a copy of it, with the frame's visibility and the same motion
    (constant velocity so shifts ``k`` times, the last map moved by the ego motion moves ``k``
    steps, the temporal average takes its own prediction into its window)."""
    if isinstance(method, ModelMethod):
        assert method.last is not None
        return list(method.engine.roll(method.last, horizon).decided)
    native = getattr(method, "ahead", None)
    if callable(native):  # predicts k ahead itself (the tracker moves each object k steps)
        return list(native(horizon))
    rolled, ahead = copy.deepcopy(method), [prediction]
    fed_extra = {key: value for key, value in extra.items() if key != "next_motion"}
    for _ in range(horizon - 1):
        fed = (ahead[-1] >= THRESHOLD).astype(np.float32)
        ahead.append(rolled.update(fed, visibility, **fed_extra))  # type: ignore[arg-type]
    return ahead


def _changed(last: np.ndarray, truth: np.ndarray) -> np.ndarray:
    return np.asarray(last, bool) != np.asarray(truth, bool)


def _counts(horizon: int) -> list[Counts]:
    return [Counts() for _ in range(horizon)]


def _f1(counts: list[Counts]) -> list[float]:
    return [c.f1 for c in counts]
