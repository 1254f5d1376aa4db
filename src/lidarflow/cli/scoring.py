"""``evaluate``: models beside the baselines, streaming over recordings."""

from __future__ import annotations

import contextlib
import dataclasses
import json
from pathlib import Path
from typing import Annotated, Any

import typer

from lidarflow.atomic import atomic_path, write_text
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
    eval_progress,
    load_input,
    progress_bar,
    refuse_existing,
    use_threads,
)
from lidarflow.predict.baselines import TA_THRESHOLD, TA_WINDOW


def _above_zero(value: float) -> float:
    """A usage error for 0: typer's ``min`` is inclusive, and a temporal-average threshold of 0
    would call every cell occupied (the baseline refuses it, which was a crash here)."""
    if value <= 0.0:
        raise typer.BadParameter(f"must be above 0, not {value}")
    return value


def methods_and_config(
    sources: list[Path | None],
    ta_window: int = TA_WINDOW,
    ta_threshold: float = TA_THRESHOLD,
    moving_threshold: float | None = None,
    ego_oracle: bool = False,
    online: bool = False,
    res: float = 0.1,
) -> tuple[list[Any], dict[str, Any]]:
    """The baselines plus one method per model source (``None``: the bundled model), and the
    configuration that describes them for the report. With an ego-motion model among them the
    last map moved by the same motion comes too (``copy_last_ego``: odometry, or on a recording
    without poses the motion matched from its scans), to show what the model adds to ego-motion
    compensation alone; ``ego_oracle`` adds the variants that know the
    true next pose; ``online`` adds, for each model, the decision rule it was not built with:
    ``NAME_online`` (offsets chosen on the recording as it streams) or ``NAME_fixed``."""
    from lidarflow.evaluate.ego import CopyLastEgo
    from lidarflow.evaluate.model_method import ModelMethod
    from lidarflow.evaluate.report import ORACLE_SUFFIX
    from lidarflow.models.presets import resolve_model
    from lidarflow.models.weights import describe_source
    from lidarflow.predict.baselines import ConstantVelocity, CopyLast, TemporalAverage
    from lidarflow.predict.decision import OnlineDecisionConfig
    from lidarflow.predict.moving import MOVING_THRESHOLD

    if moving_threshold is None:
        moving_threshold = MOVING_THRESHOLD
    methods: list[Any] = [CopyLast(), TemporalAverage(ta_window, ta_threshold), ConstantVelocity()]
    # An online decision measures itself against the temporal average reported here.
    online_config = OnlineDecisionConfig(ta_window=ta_window, ta_threshold=ta_threshold)
    models_used = {}
    for source in sources:
        net, card = resolve_model(source)
        name = "bundled" if source is None else describe_source(source)
        while name in {m.name for m in methods}:
            name += "_"
        own = card["decision"]  # the decision policy the model ships with
        method = ModelMethod(
            name, net, moving_threshold, online_config=online_config, res=res, decision=own
        )
        methods.append(method)
        keys = ("model", "weights_path", "weights_sha256", "grid")
        models_used[name] = {k: card.get(k) for k in keys}
        if method.takes.motion and ego_oracle:
            methods.append(ModelMethod(name + ORACLE_SUFFIX, net, oracle=True, res=res))
        if online:  # the other decision rule beside the model's own
            wants_online = method.online is not None
            methods.append(
                ModelMethod(
                    name + ("_fixed" if wants_online else "_online"),
                    net,
                    moving_threshold,
                    online=not wants_online,
                    online_config=online_config,
                    res=res,
                    decision=own,
                )
            )
    if any(m.takes.motion for m in methods):
        methods[3:3] = [CopyLastEgo()] + ([CopyLastEgo(oracle=True)] if ego_oracle else [])
    config = {
        "threshold": 0.4,
        # what knows the future or only moves the last map is reported, never judged
        "no_verdict": [
            m.name for m in methods if getattr(m, "oracle", False) or isinstance(m, CopyLastEgo)
        ],
        "temporal_average": {
            "window": ta_window,
            "threshold": ta_threshold,
            "chosen": "the default: of a grid of windows and thresholds, the highest mean F1 on "
            "the development recordings among settings that predict changes "
            "(docs/research/temporal_average/)"
            if (ta_window, ta_threshold) == (TA_WINDOW, TA_THRESHOLD)
            else "given on the command line",
        },
        "constant_velocity": "best integer rigid shift (radius 3 cells) of the last two maps",
        # how a reading became a map (lidarflow.scan), since it changed: numbers made under
        # another rule are not these
        "beams": "a return where range_min <= range < range_max; range_max itself, beyond and "
        "+inf no return (free to range_max), and in a scan with 1 % of its beams at range_max "
        "also readings within 1 % (3 cm) under it; NaN, -inf, 0 and below range_min unknown",
        "models": models_used,
        "calibration": {"bins": 10, "over": "every cell of every scored frame"},
        "moving_segmentation": {
            "threshold_cells": moving_threshold,
            "rule": "occupied and |forward flow - fitted background flow| > threshold",
        },
    }
    if online or any(getattr(m, "online", None) is not None for m in methods):
        config["online_decision"] = {
            **dataclasses.asdict(online_config),
            "rule": "each frame, the (occupied, free) offset pair, on the last map moved by the "
            "flow or unmoved, that would leave the recording's win margin over the three "
            "baselines largest if the next `lookahead` frames went as its recent (decayed) ones; "
            "the decisions made and the baselines' counts decay by `history_decay`",
        }
    if any(m.takes.motion for m in methods):
        config["ego_motion"] = (
            "models built with ego_motion get the recordings' poses (odometry); the motion to "
            "the next frame is the last one again (constant velocity, causal); *_oracle* "
            "variants use the true next pose instead; copy_last_ego moves the last map by the same "
            "motion (reported beside, not one of the three baselines a model must beat); "
            "on a recording without poses, models built with poses_optional (the head recipe's, "
            "the bundled one) and copy_last_ego get the motion matched from the scans "
            "(lidarflow.motion.scanmatch; uncompensated where no match counts)"
        )
    return methods, config


@app.command()
def evaluate(
    inputs: Annotated[
        list[Path], typer.Argument(help="Recordings (.npz) or bags/MCAP to evaluate on.")
    ],
    topic: TopicOpt = None,
    odom_topic: OdomOpt = None,
    model: Annotated[
        list[Path] | None,
        typer.Option(
            "--model",
            "-m",
            help=f"Trained model to score beside the baselines: {TORCH_MODEL_SOURCES} or "
            "`bundled` (the default); not an .onnx file. Repeatable.",
        ),
    ] = None,
    baselines_only: Annotated[
        bool,
        typer.Option(
            "--baselines-only", help="Score the baselines alone (no model; not with --model)."
        ),
    ] = False,
    output: Annotated[
        Path | None,
        typer.Option("--output", "-o", help="Write the full report (JSON) to this file."),
    ] = None,
    report_dir: Annotated[
        Path | None,
        typer.Option(
            "--report",
            help="Folder to write an HTML report to (index.html: PR curves, overlay GIFs, "
            "report.json).",
        ),
    ] = None,
    gif_frames: Annotated[
        int, typer.Option(help="Frames per overlay GIF in the report.", min=1)
    ] = 100,
    warmup: Annotated[
        int, typer.Option(help="Frames per recording that only warm the state up.", min=0)
    ] = 10,
    ta_window: Annotated[
        int,
        typer.Option(
            help="Temporal-average baseline: frames averaged.",
            min=1,
        ),
    ] = TA_WINDOW,
    ta_threshold: Annotated[
        float,
        typer.Option(
            help="Temporal-average baseline: occupied when mean >= this (above 0, at most 1).",
            min=0.0,
            max=1.0,
            callback=_above_zero,
        ),
    ] = TA_THRESHOLD,
    ego_oracle: Annotated[
        bool,
        typer.Option(
            "--ego-oracle",
            help="Also score ego-motion models told the true next pose (an upper bound).",
        ),
    ] = False,
    horizon: Annotated[
        int,
        typer.Option(
            min=1,
            help="Also score F1 1..K frames ahead (models fed their own predictions).",
        ),
    ] = 1,
    online_decision: Annotated[
        bool,
        typer.Option(
            "--online-decision",
            help="Score each occupancy-head model with both decision rules, fixed and online "
            "offsets (the other one as NAME_fixed or NAME_online).",
        ),
    ] = False,
    grid: GridOpt = 100,
    res: ResOpt = 0.1,
    moving_threshold: MovingOpt = None,
    force: ForceOpt = False,
    threads: ThreadsOpt = DEFAULT_THREADS,
    json_out: Annotated[Path | None, typer.Option("--json", hidden=True)] = None,
) -> None:
    """Score next-map prediction on each recording, streaming, for the baselines (copy-last,
    temporal average, constant velocity) and each --model (default: the bundled one): F1 at
    0.4, precision, recall, average precision, changed-cell F1, calibration, and flow error and
    moving segmentation where the recording has ground truth.

    A model wins when its F1 beats the best baseline's and its changed-cell F1 every
    baseline's. Steps across gaps in time are not scored; -o writes every number as JSON."""
    from lidarflow.evaluate.report import (
        format_comparison,
        format_table,
        format_uncertainty_table,
        gaps_note,
        grid_note,
        undefined_note,
    )
    from lidarflow.predict.backends import recorded_grid
    from lidarflow.scan import GridSpec
    from lidarflow.viz.evaluation import evaluate_and_report

    if baselines_only and model:
        raise typer.BadParameter("--baselines-only scores no model; drop --model or it")
    if json_out is not None:  # the spelling before -o/--output, kept working
        if output is not None:
            raise typer.BadParameter("give -o/--output once (--json is its old name)")
        output = json_out
    refuse_existing(output, force=force)
    refuse_existing(report_dir, force=force, marker="index.html")
    use_threads(threads)
    sources: list[Path | None] = list(model or [])
    if not sources and not baselines_only:
        if bundled_model_available():
            sources = [None]
        else:
            typer.echo("no bundled model in this installation: scoring the baselines only")
    spec = GridSpec(grid, grid, res)
    named = []
    for path in inputs:
        recording = load_input(path, topic, odom_topic)
        _check_length(str(path), recording, warmup, horizon)
        named.append((str(path), recording))
    methods, config = methods_and_config(
        sources,
        ta_window,
        ta_threshold,
        moving_threshold,
        ego_oracle,
        online_decision,
        spec.res,
    )
    config.update({"warmup": warmup, "grid": spec.to_dict()})
    for name, used in config["models"].items():
        trained = recorded_grid(used)
        if trained is not None and trained != spec:
            typer.echo(
                f"note: {name} was trained on a {trained.height}x{trained.width} grid of "
                f"{trained.res:g} m and is scored on {spec.height}x{spec.width} of {spec.res:g} m "
                f"(--grid {trained.height} --res {trained.res:g} scores it on its own)",
                err=True,
            )
    with contextlib.ExitStack() as stack:  # the report folder appears once complete
        staged = None if report_dir is None else stack.enter_context(atomic_path(report_dir))
        report = evaluate_and_report(
            named, methods, spec, warmup, config, staged, gif_frames, eval_progress
        )
    if horizon > 1:
        _add_horizon_scores(report, named, methods, spec, warmup, horizon)
    for entry in report["recordings"]:
        title = f"{entry['path']} ({entry['frames_evaluated']} frames{gaps_note(entry)})"
        typer.echo(format_table(entry["methods"], title))
        for note in (undefined_note(entry.get("undefined", [])), grid_note(entry, config["grid"])):
            if note:
                typer.echo(note)
        comparison = format_comparison(entry["against_baselines"])
        typer.echo((comparison + "\n") if comparison else "")
        if "horizon_f1" in entry:
            typer.echo(_format_horizon(entry["horizon_f1"]) + "\n")
        extra = format_uncertainty_table(entry["methods"], "calibration and moving segmentation")
        if extra:
            typer.echo(extra + "\n")
    if len(report["recordings"]) > 1:
        typer.echo(format_table(report["overall"], "overall (micro-averaged)"))
        note = undefined_note(report.get("undefined", []))
        if note:
            typer.echo(note)
        if report["against_baselines"]:
            typer.echo(format_comparison(report["against_baselines"]))
        extra = format_uncertainty_table(report["overall"], "overall calibration and segmentation")
        if extra:
            typer.echo(extra)
    if output is not None:
        write_text(output, json.dumps(report, indent=2))
        typer.echo(f"wrote {output}")
    if report_dir is not None:
        typer.echo(f"wrote {report_dir / 'index.html'}")


def _check_length(name: str, recording: Any, warmup: int, horizon: int) -> None:
    """Refuse a recording too short to score, naming it, as soon as it is read: not after the
    long scoring of the ones before it."""
    from lidarflow.data.gaps import frames_after_gaps
    from lidarflow.evaluate.horizon import scored_frames
    from lidarflow.evaluate.stream import check_length

    gaps = frames_after_gaps(recording.stamps_ns)
    check_length(len(recording), warmup, gaps, name)
    if horizon > 1:
        scored_frames(len(recording), horizon, warmup, gaps, name)


def _add_horizon_scores(
    report: dict[str, Any],
    named: list[tuple[str, Any]],
    methods: list[Any],
    spec: Any,
    warmup: int,
    horizon: int,
) -> None:
    from lidarflow.evaluate.horizon import horizon_f1
    from lidarflow.evaluate.model_method import ModelMethod
    from lidarflow.evaluate.stream import recording_inputs

    # one roll-out per model (an oracle variant has no roll-out of its own)
    streamed = [m for m in methods if isinstance(m, ModelMethod) and not m.oracle]
    for entry, (name, recording) in zip(report["recordings"], named, strict=True):
        inputs = recording_inputs(recording, spec, streamed)
        total = len(streamed) * max(0, len(inputs.occupancy) - horizon)
        with progress_bar(total, f"horizon {horizon}, {Path(name).name}") as bar:
            entry["horizon_f1"] = horizon_f1(
                inputs.occupancy, inputs.visibility, streamed, horizon, warmup, bar.update,
                inputs.motions, inputs.returns, inputs.motions_from_poses, inputs.subcell,
                inputs.gaps, inputs.paces,
            )  # fmt: skip


def _format_horizon(scores: dict[str, list[float]]) -> str:
    k = len(next(iter(scores.values())))
    lines = ["F1 per horizon step     " + "".join(f"{f'k={i + 1}':>10}" for i in range(k))]
    for name, values in scores.items():
        lines.append(f"{name:<24}" + "".join(f"{v:>10.4f}" for v in values))
    return "\n".join(lines)
