"""What ``evaluate`` and ``predict`` do to one input, the work ``--jobs`` hands a worker
(:mod:`lidarflow.cli.jobs`): each takes a picklable task and returns a picklable result."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from lidarflow.cli.worker import job_bar

if TYPE_CHECKING:
    from lidarflow.evaluate.evaluation import Scored

__all__ = [
    "EvaluateSettings",
    "PredictSettings",
    "PredictTask",
    "Predicted",
    "build_methods",
    "methods_kept",
    "predict_input",
    "score_input",
]


@dataclass(frozen=True)
class EvaluateSettings:
    """What every recording of one ``evaluate`` run is scored with: the methods' settings, the
    grid, the warm-up, the horizon and the (staged) report folder for the pictures."""

    sources: tuple[Path | None, ...]
    ta_window: int
    ta_threshold: float
    moving_threshold: float | None
    ego_oracle: bool
    online_decision: bool
    spec: Any  # GridSpec
    device: str
    threads: int
    warmup: int
    horizon: int
    report_dir: Path | None
    gif_frames: int
    combine: bool | None = None  # None: as predict runs the model by default
    learn: bool = False


def build_methods(settings: EvaluateSettings) -> tuple[list[Any], dict[str, Any]]:
    """The methods ``settings`` ask for and the report's config
    (:func:`lidarflow.evaluate.methods.methods_and_config`), the same in the command and in
    every worker."""
    from lidarflow.evaluate.methods import methods_and_config

    s = settings
    return methods_and_config(
        list(s.sources), s.ta_window, s.ta_threshold, s.moving_threshold, s.ego_oracle,
        s.online_decision, s.spec.res, device=s.device, threads=s.threads or None,
        combine=s.horizon if s.combine else None, learn=s.learn,
        combined_ahead=None if s.combine is False else s.horizon,
    )  # fmt: skip


#: The methods a worker built, by the settings they were built for: made once per process, as
#: the one-process run makes them once, and reset between recordings alike.
_METHODS: dict[EvaluateSettings, list[Any]] = {}


def _methods(settings: EvaluateSettings) -> list[Any]:
    if settings not in _METHODS:
        _METHODS[settings] = build_methods(settings)[0]
    return _METHODS[settings]


@contextlib.contextmanager
def methods_kept(settings: EvaluateSettings, methods: list[Any]) -> Iterator[None]:
    """Within it, score ``settings`` with ``methods`` in this process: a run of one worker
    scores here, with the methods the command built."""
    _METHODS[settings] = methods
    try:
        yield
    finally:
        _METHODS.pop(settings, None)


def score_input(task: tuple[str, Any, str, EvaluateSettings, Any]) -> Scored:
    """Score the recording of ``task`` (name, recording, picture stem, settings, its labels or
    ``None``) with :func:`lidarflow.evaluate.evaluation.score_one`."""
    from lidarflow.evaluate.evaluation import score_one
    from lidarflow.viz.evaluation import ReportFigures

    name, recording, stem, settings, labels = task
    figures = None
    if settings.report_dir is not None:
        figures = ReportFigures(settings.report_dir, settings.gif_frames)
    with job_bar(len(recording) - 1, f"evaluating {Path(name).name}") as bar:
        return score_one(
            name, recording, _methods(settings), settings.spec, settings.warmup,
            settings.horizon, stem, figures, bar.update, labels=labels,
        )  # fmt: skip


@dataclass(frozen=True)
class PredictSettings:
    """What every input of one ``predict`` run is predicted with (its options)."""

    topic: str | None
    odom_topic: str | None
    model: Path | None
    grid: Any  # GridSpec or None: the model's own
    horizon: int
    threads: int
    moving_threshold: float
    online_decision: bool | None
    groups: frozenset[str]
    force: bool
    combine: bool | None = None  # None: the Predictor's default
    learn: bool = False


@dataclass(frozen=True)
class PredictTask:
    input: Path
    output: Path
    settings: PredictSettings


@dataclass(frozen=True)
class Predicted:
    """One input predicted: the messages written per topic, and whether the model had flow to
    write (``--topics ...,flow``)."""

    counts: dict[str, int]
    has_flow: bool


def predict_input(task: PredictTask) -> Predicted:
    """Read ``task.input``, predict every scan of it and write ``task.output``."""
    from lidarflow.cli.app import load_input
    from lidarflow.cli.scorable import refuse_without_returns, warn_unknown_beams
    from lidarflow.data.sources import is_recording_file
    from lidarflow.evaluate.horizon import check_horizon
    from lidarflow.outputs.job import predict_to_bag
    from lidarflow.predict import Predictor

    s = task.settings
    recording = load_input(task.input, s.topic, s.odom_topic)
    refuse_without_returns(task.input, recording, "predict on")
    warn_unknown_beams(task.input, recording)
    check_horizon(len(recording), s.horizon, 0, str(task.input))
    predictor = Predictor(
        s.model,
        s.grid,
        horizon=s.horizon,
        threads=s.threads or None,
        moving_threshold=s.moving_threshold,
        online_decision=s.online_decision,
        combine=s.combine,
        learn=s.learn,
    )
    source = None if is_recording_file(task.input) else task.input
    with job_bar(len(recording), f"predicting {task.input.name}") as bar:
        counts = predict_to_bag(
            recording, predictor, task.output, bar.update, s.force, s.groups, source
        )
    return Predicted(counts, predictor.backend.capabilities.flow)
