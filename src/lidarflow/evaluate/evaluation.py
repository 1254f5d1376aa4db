"""``lidarflow evaluate``'s work: score methods on recordings and assemble the report.

:func:`score_one` scores one recording in one pass (``evaluate --jobs N`` runs it in N worker
processes, :func:`evaluate_and_report` in turn); :func:`report_of` assembles the report from
the recordings scored, in order. Pictures are drawn by the :class:`Figures` handed in
(``lidarflow.viz.evaluation.ReportFigures``): scoring does not draw.
"""

from __future__ import annotations

import contextlib
import functools
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from lidarflow.baselines import Method
from lidarflow.data.info import find_gaps
from lidarflow.data.recording import Recording
from lidarflow.evaluate.horizon import horizon_entry
from lidarflow.evaluate.labels import Labels, LabelScore, labels_entry, with_labels
from lidarflow.evaluate.report import add_horizon_verdict, build_report, count_recordings_won
from lidarflow.evaluate.runner import (
    Hooks,
    OnAhead,
    OnMoving,
    OnPrediction,
    recording_truth,
    score_stream,
)
from lidarflow.evaluate.scoring import Scorer
from lidarflow.evaluate.stream import (
    RecordingInputs,
    has_ground_truth,
    other_recorded_grid,
    recording_inputs,
)
from lidarflow.motion.odometry import pose_jumps
from lidarflow.scan import GridSpec

__all__ = [
    "Figures",
    "RecordingFigures",
    "Scored",
    "evaluate_and_report",
    "recording_notes",
    "report_of",
    "safe_stem",
    "score_one",
    "unique_stems",
]

#: A figure of a report: its caption and its file.
Figure = tuple[str, Path]


class RecordingFigures(Protocol):
    """Draws one recording's pictures while it is scored (the runner's hooks); ``finish``
    draws the rest from its scorers and returns every figure."""

    on_prediction: OnPrediction
    on_moving: OnMoving

    def finish(self, scorers: Mapping[str, Scorer]) -> list[Figure]: ...


class Figures(Protocol):
    """What draws an evaluation's pictures and writes its report folder."""

    def recording(
        self, name: str, stem: str, recording: Recording, inputs: RecordingInputs
    ) -> RecordingFigures:
        """The drawing of the recording ``name`` (files named by ``stem``)."""
        ...

    def write(self, report: dict[str, Any], figures: Mapping[str, list[Figure]]) -> None:
        """Write ``report`` and its ``figures`` (per recording name)."""
        ...


@dataclass(frozen=True)
class Scored:
    """One recording scored: its scorers, figures, report notes (:func:`recording_notes`)
    and, for ``horizon`` > 1, its ``horizon_*`` keys."""

    scorers: dict[str, Scorer]
    figures: list[Figure]
    notes: dict[str, Any]
    horizon: dict[str, Any] | None


def safe_stem(path: str | Path) -> str:
    """A file-name-safe stem for a recording path (``a/b/run 1.bag`` -> ``run_1``)."""
    name = Path(path).name
    for suffix in (".bag.zip", ".bag", ".mcap", ".npz", ".db3"):
        if name.lower().endswith(suffix):
            name = name[: -len(suffix)]
            break
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name) or "recording"


def unique_stems(names: Sequence[str]) -> list[str]:
    """A file-name stem per recording name (:func:`safe_stem`), numbered where two share one
    (``a/run.bag``, ``b/run.bag`` -> ``run``, ``run_2``)."""
    stems: list[str] = []
    for name in names:
        stem, n = safe_stem(name), 1
        while stem in stems:
            n += 1
            stem = f"{safe_stem(name)}_{n}"
        stems.append(stem)
    return stems


def score_one(
    name: str,
    recording: Recording,
    methods: Sequence[Method],
    grid: GridSpec,
    warmup: int,
    horizon: int = 1,
    stem: str | None = None,
    figures: Figures | None = None,
    progress: Callable[[int], None] | None = None,
    on_ahead: Callable[[str, str, int, Any], None] | None = None,
    labels: Labels | None = None,
) -> Scored:
    """Score ``methods`` on the recording ``name`` in one pass, for ``horizon`` > 1 also
    ahead; with ``figures``, draw its pictures (files named by ``stem``, default
    :func:`safe_stem`); with ``labels`` (this recording's), score them too. ``progress(1)``
    after each frame; ``on_ahead(name, method, t, predicted)`` with each prediction ahead."""
    inputs = recording_inputs(recording, grid, methods)
    drawing = None
    if figures is not None:
        drawing = figures.recording(name, stem or safe_stem(name), recording, inputs)
    ahead: OnAhead | None = None if on_ahead is None else functools.partial(on_ahead, name)
    hooks = Hooks(
        progress,
        None if drawing is None else drawing.on_prediction,
        None if drawing is None else drawing.on_moving,
        ahead,
    )
    truth = recording_truth(recording, grid, inputs)
    scoring = None
    if labels is not None:
        assert truth.region is not None  # every recording has its dynamic region
        scoring = LabelScore(labels.positions, grid, horizon, truth.region)
        hooks = with_labels(hooks, scoring, methods, inputs.occupancy)
    scores = score_stream(inputs, methods, warmup, horizon if horizon > 1 else None, truth, hooks)
    drawn = [] if drawing is None else drawing.finish(scores.next_map)
    keys = None if scores.horizon is None else horizon_entry(scores.horizon, scores.horizon_frames)
    notes = recording_notes(recording, grid)
    if labels is not None and scoring is not None:
        notes.update(labels_entry(labels, scoring))
    return Scored(scores.next_map, drawn, notes, keys)


def recording_notes(recording: Recording, grid: GridSpec) -> dict[str, Any]:
    """What a recording's report entry says beside its scores: the gaps not scored across, the
    poses' jumps, and a grid it was recorded on other than ``grid``."""
    notes: dict[str, Any] = {}
    gaps = find_gaps(recording)
    if gaps:  # steps not scored: the frame after a gap is not the next scan
        notes["gaps_not_scored"] = [{"before_frame": i, "seconds": round(s, 3)} for i, s in gaps]
    jumps = pose_jumps(recording.poses, recording.stamps_ns)
    if jumps:  # odometry glitches: the mover region is counted in the world by these poses
        notes["pose_jumps"] = len(jumps)
        notes["first_pose_jumps"] = [{"before_frame": t, "metres": d} for t, d in jumps[:10]]
    recorded = other_recorded_grid(recording, grid)
    # a real recording is rasterized on any grid alike; a simulated one's ground truth
    # was made on its own grid and is not scored on another
    if recorded is not None and has_ground_truth(recording):
        notes["recorded_grid"] = recorded
        notes["ground_truth_not_scored"] = True
    return notes


def report_of(
    scored: Sequence[tuple[str, Scored]],
    config: dict[str, Any],
    figures: Figures | None = None,
) -> dict[str, Any]:
    """The report of the recordings ``scored`` (name, :class:`Scored`), in order, each entry
    with its notes and horizon keys; with ``figures``, written with the figures drawn."""
    report = build_report([(name, s.scorers) for name, s in scored], config)
    for entry, (_, one) in zip(report["recordings"], scored, strict=True):
        entry.update(one.notes)
        if one.horizon is not None:
            entry.update(one.horizon)
            add_horizon_verdict(entry)
    if any(one.horizon is not None for _, one in scored):
        count_recordings_won(report)
    if figures is not None:
        figures.write(report, {name: s.figures for name, s in scored})
    return report


def evaluate_and_report(
    named_recordings: Sequence[tuple[str, Recording]],
    methods: Sequence[Method],
    grid: GridSpec,
    warmup: int,
    config: dict[str, Any],
    figures: Figures | None = None,
    progress: Callable[[str, int], Any] | None = None,
    horizon: int = 1,
    on_ahead: Callable[[str, str, int, Any], None] | None = None,
) -> dict[str, Any]:
    """:func:`score_one` of each recording in turn, and their :func:`report_of`.
    ``progress(name, total)`` may return a context manager with ``update(n)`` (a tqdm bar)."""
    names = [name for name, _ in named_recordings]
    scored = []
    for (name, recording), stem in zip(named_recordings, unique_stems(names), strict=True):
        bar = progress(name, len(recording) - 1) if progress else contextlib.nullcontext()
        with bar as b:
            one = score_one(
                name, recording, methods, grid, warmup, horizon, stem, figures,
                getattr(b, "update", None), on_ahead,
            )  # fmt: skip
        scored.append((name, one))
    return report_of(scored, config, figures)
