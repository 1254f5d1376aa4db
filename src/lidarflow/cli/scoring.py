"""``evaluate``: models beside the baselines, streaming over recordings."""

from __future__ import annotations

import contextlib
import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

import typer

from lidarflow.atomic import atomic_path, write_text
from lidarflow.baselines import TA_THRESHOLD, TA_WINDOW
from lidarflow.cli.app import (
    DEFAULT_THREADS,
    TORCH_MODEL_SOURCES,
    ForceOpt,
    GridOpt,
    MovingOpt,
    OdomOpt,
    ResOpt,
    ThreadsOpt,
    TopicOpt,
    app,
    bundled_model_available,
    combine_choice,
    refuse_existing,
    use_threads,
)
from lidarflow.cli.jobs import JobsOpt
from lidarflow.cli.options import command_options
from lidarflow.cli.per_input import EvaluateSettings, build_methods


def _above_zero(value: float) -> float:
    """A usage error for 0 (typer's ``min`` is inclusive): a temporal-average threshold of 0
    would call every cell occupied."""
    if value <= 0.0:
        raise typer.BadParameter(f"must be above 0, not {value}")
    return value


@dataclass(frozen=True)
class EvaluateOptions:
    """``evaluate``'s command line."""

    inputs: Annotated[
        list[Path], typer.Argument(help="Recordings (.npz) or bags/MCAP to evaluate on.")
    ]
    topic: TopicOpt = None
    odom_topic: OdomOpt = None
    model: Annotated[
        list[Path] | None,
        typer.Option(
            "--model",
            "-m",
            help=f"Trained model to score beside the baselines: {TORCH_MODEL_SOURCES}, an "
            ".onnx file from `lidarflow export`, or `bundled` (the default). Repeatable.",
        ),
    ] = None
    baselines_only: Annotated[
        bool,
        typer.Option(
            "--baselines-only", help="Score the baselines alone (no model; not with --model)."
        ),
    ] = False
    output: Annotated[
        Path | None,
        typer.Option("--output", "-o", help="Write the full report (JSON) to this file."),
    ] = None
    report_dir: Annotated[
        Path | None,
        typer.Option(
            "--report",
            help="Folder to write an HTML report to (index.html: PR curves, overlay GIFs, "
            "report.json).",
        ),
    ] = None
    gif_frames: Annotated[
        int, typer.Option(help="Frames per overlay GIF in the report.", min=1)
    ] = 100
    warmup: Annotated[
        int, typer.Option(help="Frames per recording that only warm the state up.", min=0)
    ] = 10
    ta_window: Annotated[
        int,
        typer.Option(
            help="Temporal-average baseline: frames averaged.",
            min=1,
        ),
    ] = TA_WINDOW
    ta_threshold: Annotated[
        float,
        typer.Option(
            help="Temporal-average baseline: occupied when mean >= this (above 0, at most 1).",
            min=0.0,
            max=1.0,
            callback=_above_zero,
        ),
    ] = TA_THRESHOLD
    ego_oracle: Annotated[
        bool,
        typer.Option(
            "--ego-oracle",
            help="Also score ego-motion models told the true next pose (an upper bound).",
        ),
    ] = False
    horizon: Annotated[
        int,
        typer.Option(
            min=1,
            help="Also score F1 1..K frames ahead (models fed their own predictions).",
        ),
    ] = 1
    legs: Annotated[
        list[Path] | None,
        typer.Option(
            "--legs",
            help="Labelled movers to score 1..K ahead (recall and precision within 0.3 m): "
            "leg_tracker's extracted bag, or a bag with /ground_truth_people_tracks. One per "
            "recording, in their order.",
        ),
    ] = None
    online_decision: Annotated[
        bool,
        typer.Option(
            "--online-decision",
            help="Score each occupancy-head model with both decision rules, fixed and online "
            "offsets (the other one as NAME_fixed or NAME_online).",
        ),
    ] = False
    combine: Annotated[
        bool,
        typer.Option(
            "--combine",
            help="Also score each model combined online with the simple predictors at every "
            "frame ahead (NAME_combined).",
        ),
    ] = False
    no_combine: Annotated[
        bool,
        typer.Option(
            "--no-combine",
            help="Score the models' frames 2..--horizon without the online combination, which "
            "decides them by default (as in predict).",
        ),
    ] = False
    learn: Annotated[
        bool,
        typer.Option(
            "--learn",
            help="Also score each head-only model with its head learning on the stream, from "
            "the shipped weights at every recording (NAME_learning).",
        ),
    ] = False
    grid: GridOpt = 100
    res: ResOpt = 0.1
    moving_threshold: MovingOpt = None
    force: ForceOpt = False
    threads: ThreadsOpt = DEFAULT_THREADS
    jobs: JobsOpt = 1
    device: Annotated[
        str,
        typer.Option(
            help="Where PyTorch models run: cpu, cuda, or auto (CUDA if available). ONNX files "
            "and the baselines run on the CPU."
        ),
    ] = "cpu"
    json_out: Annotated[Path | None, typer.Option("--json", hidden=True)] = None


@app.command()
@command_options(EvaluateOptions)
def evaluate(options: EvaluateOptions) -> None:
    """Score next-map prediction on each recording, streaming, for the baselines (copy-last,
    temporal average, constant velocity, tracker) and each --model (default: the bundled one):
    F1, AP, changed-cell F1, calibration, and mover F1 (exact and within 0.2 m, in the cells
    something moved through). A model wins when its F1 beats the best baseline's, its
    changed-cell F1 every baseline's and its tolerant mover F1 copy-last's (at k=1 and at
    --horizon). -o writes every number as JSON."""
    from lidarflow.cli.jobs import resolve_jobs
    from lidarflow.cli.per_input import methods_kept
    from lidarflow.cli.scorable import read_scorable

    o = options
    output = _checked_output(o)
    read = [*o.inputs, *(o.model or []), *(o.legs or [])]
    refuse_existing(output, force=o.force, inputs=read)
    refuse_existing(o.report_dir, force=o.force, folder=True, inputs=read)
    use_threads(o.threads)
    sources = _sources(o)
    named = [
        (str(path), read_scorable(path, o.topic, o.odom_topic, o.warmup, o.horizon, o.ego_oracle))
        for path in o.inputs
    ]
    labels = _labels(o.legs, named)
    settings = _settings(o, sources)
    methods, config = build_methods(settings)
    config.update({"warmup": o.warmup, "grid": settings.spec.to_dict()})
    _note_other_grids(config["models"], settings.spec)
    workers = resolve_jobs(o.jobs, len(named))
    with contextlib.ExitStack() as stack:  # the report folder appears once complete
        if o.report_dir is not None:
            staged = stack.enter_context(atomic_path(o.report_dir))
            settings = dataclasses.replace(settings, report_dir=staged)
        with methods_kept(settings, methods):  # one worker scores here, with these
            report = _evaluate_in_jobs(named, labels, settings, config, workers)
    _say_report(report, config, output, o.report_dir)


def _checked_output(options: EvaluateOptions) -> Path | None:
    """``-o``, or the ``--json`` it replaced; a usage error where the flags contradict."""
    if options.baselines_only and options.model:
        raise typer.BadParameter("--baselines-only scores no model; drop --model or it")
    if options.legs and len(options.legs) != len(options.inputs):
        raise typer.BadParameter(
            f"give one --legs per recording, in their order: {len(options.inputs)} "
            f"recording{'s' * (len(options.inputs) != 1)}, {len(options.legs)} --legs"
        )
    if options.json_out is None:
        return options.output
    if options.output is not None:  # the spelling before -o/--output, kept working
        raise typer.BadParameter("give -o/--output once (--json is its old name)")
    return options.json_out


def _labels(legs: list[Path] | None, named: list[tuple[str, Any]]) -> list[Any]:
    """Each recording's labels (:func:`lidarflow.evaluate.labels.read_labels`; ``None``
    without ``--legs``), read before any recording is scored: a bad file fails at once."""
    from lidarflow.evaluate.labels import read_labels

    if not legs:
        return [None] * len(named)
    return [read_labels(path, recording) for path, (_, recording) in zip(legs, named, strict=True)]


def _sources(options: EvaluateOptions) -> list[Path | None]:
    """The models to score (``None``: the bundled one), none with ``--baselines-only`` or
    where this installation has no bundled model (said)."""
    sources: list[Path | None] = list(options.model or [])
    if not sources and not options.baselines_only:
        if bundled_model_available():
            sources = [None]
        else:
            typer.echo("no bundled model in this installation: scoring the baselines only")
    return sources


def _settings(o: EvaluateOptions, sources: list[Path | None]) -> EvaluateSettings:
    from lidarflow.predict.backends import resolve_device
    from lidarflow.scan import GridSpec

    return EvaluateSettings(
        tuple(sources), o.ta_window, o.ta_threshold, o.moving_threshold, o.ego_oracle,
        o.online_decision, GridSpec(o.grid, o.grid, o.res), resolve_device(o.device), o.threads,
        o.warmup, o.horizon, None, o.gif_frames,
        combine_choice(o.combine, o.no_combine), o.learn,
    )  # fmt: skip


def _say_report(
    report: dict[str, Any], config: dict[str, Any], output: Path | None, report_dir: Path | None
) -> None:
    """Each recording's scores, the overall ones, and what was written."""
    from lidarflow.cli.scorable import warn_nothing_scored
    from lidarflow.evaluate.summary import format_overall, format_recording

    for entry in report["recordings"]:
        warn_nothing_scored(entry)
        typer.echo(format_recording(entry, config["grid"]))
    if len(report["recordings"]) > 1:
        typer.echo(format_overall(report))
    if output is not None:
        write_text(output, json.dumps(report, indent=2))
        typer.echo(f"wrote {output}")
    if report_dir is not None:
        typer.echo(f"wrote {report_dir / 'index.html'}")


def _note_other_grids(models: dict[str, Any], spec: Any) -> None:
    """Say on stderr which of the ``models`` (their records) are scored on a grid other than
    their own."""
    from lidarflow.predict.backends import recorded_grid

    for name, used in models.items():
        trained = recorded_grid(used)
        if trained is not None and trained != spec:
            typer.echo(
                f"note: {name} was trained on a {trained.height}x{trained.width} grid of "
                f"{trained.res:g} m and is scored on {spec.height}x{spec.width} of {spec.res:g} m "
                f"(--grid {trained.height} --res {trained.res:g} scores it on its own)",
                err=True,
            )


def _evaluate_in_jobs(
    named: list[tuple[str, Any]],
    labels: list[Any],
    settings: EvaluateSettings,
    config: dict[str, Any],
    workers: int,
) -> dict[str, Any]:
    """``evaluate``'s report, one worker per recording (:mod:`lidarflow.cli.jobs`). The first
    recording that fails stops the others: the report needs every one."""
    from lidarflow.cli.jobs import Outcome, run_jobs
    from lidarflow.cli.per_input import score_input
    from lidarflow.errors import EvaluateError
    from lidarflow.evaluate.evaluation import report_of, unique_stems
    from lidarflow.viz.evaluation import ReportFigures

    names = [name for name, _ in named]
    stems = unique_stems(names)
    tasks = [
        (n, rec, stem, settings, legs)
        for (n, rec), stem, legs in zip(named, stems, labels, strict=True)
    ]

    def show(outcome: Outcome) -> None:  # a recording's notes, in input order
        if outcome.notes:
            typer.echo(outcome.notes, err=True, nl=False)

    desc = f"evaluating {len(named)} recordings, {workers} at once"
    outcomes = run_jobs(score_input, tasks, names, workers, settings.threads, desc, show, True)
    for outcome in outcomes:
        if outcome.error is not None:
            others = " (the other recordings were stopped: nothing is written without every one)"
            raise EvaluateError(outcome.error + (others if len(named) > 1 else ""))
    figures = None
    if settings.report_dir is not None:
        figures = ReportFigures(settings.report_dir, settings.gif_frames)
    scored = [(name, outcome.value) for name, outcome in zip(names, outcomes, strict=True)]
    return report_of(scored, config, figures)
