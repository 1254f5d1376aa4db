"""``demo``, ``predict`` and ``export``: the bundled model and trained ones put to work."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

import typer

from lidarflow.atomic import write_text
from lidarflow.cli.app import (
    DEFAULT_THREADS,
    CombineOpt,
    ExportModelOpt,
    ForceOpt,
    LearnOpt,
    ModelGridOpt,
    ModelOpt,
    ModelResOpt,
    MovingOpt,
    NoCombineOpt,
    OdomOpt,
    ThreadsOpt,
    TopicOpt,
    app,
    bundled_model_available,
    combine_choice,
    completed_grid,
    eval_progress,
    load_input,
    model_grid,
    progress_bar,
    refuse_existing,
    use_threads,
)
from lidarflow.cli.jobs import JobsOpt
from lidarflow.cli.options import command_options
from lidarflow.evaluate.methods import methods_and_config


@app.command()
def demo(
    output: Annotated[
        Path, typer.Option("--output", "-o", help="Folder for the demo's outputs.")
    ] = Path("demo_out"),
    force: ForceOpt = False,
    threads: ThreadsOpt = DEFAULT_THREADS,
) -> None:
    """Run the main job on the bundled sample recording: convert it, draw a frame, predict
    every next map with the bundled model, score it beside the baselines (report.json and an
    HTML page), and write the predictions as an MCAP file for Foxglove."""
    from lidarflow.atomic import atomic_path

    refuse_existing(output, force=force, folder=True)
    use_threads(threads)
    with atomic_path(output) as folder:  # the folder appears once complete
        folder.mkdir()
        _demo(folder, output)


def _demo(folder: Path, output: Path) -> None:
    """``demo``'s work, written into ``folder``, which becomes ``output`` once complete."""
    from lidarflow.data import SAMPLE_TOPIC, describe_recording, sample_bag_path
    from lidarflow.evaluate.evaluation import evaluate_and_report
    from lidarflow.evaluate.report import format_comparison, format_table
    from lidarflow.scan import GridSpec
    from lidarflow.viz.evaluation import ReportFigures
    from lidarflow.viz.maps import draw_maps

    bag = sample_bag_path()
    recording = load_input(bag, SAMPLE_TOPIC)
    recording.save(folder / "sample.npz")
    summary = describe_recording(recording)
    typer.echo(
        f"sample: {bag.name} ({summary['scans']} scans, {summary['frame_rate_hz']} Hz, "
        f"{summary['beams_per_scan']} beams) -> {output / 'sample.npz'}"
    )
    spec = GridSpec()
    frame = len(recording) // 2
    occ, vis = recording.maps(spec, frame, frame + 1)
    draw_maps(occ[0], vis[0], folder / "maps.png", spec, title=f"{bag.name} frame {frame}")
    typer.echo(f"maps of frame {frame}: {output / 'maps.png'}")
    has_model = bundled_model_available()
    if not has_model:
        typer.echo("no bundled model in this installation: scoring the baselines only")
    methods, config = methods_and_config([None] if has_model else [])
    config.update({"warmup": 10, "grid": spec.to_dict()})
    figures = ReportFigures(folder / "report", 60)
    report = evaluate_and_report(
        [(str(bag), recording)], methods, spec, 10, config, figures, eval_progress
    )
    write_text(folder / "results.json", json.dumps(report, indent=2))
    entry = report["recordings"][0]
    title = f"next-map prediction, {entry['frames_evaluated']} frames"
    typer.echo(format_table(entry["methods"], title))
    if entry["against_baselines"]:
        typer.echo(format_comparison(entry["against_baselines"]))
        # honest about what this number is: the bundled model trained on every dev recording
        typer.echo(
            "(in-sample: the bundled model trained on this recording; on recordings it never "
            "saw, see the README's 'Results on recordings it never saw')"
        )
    typer.echo(f"results: {output / 'results.json'}; report: {output / 'report' / 'index.html'}")
    if has_model:
        from lidarflow.outputs.job import predict_to_bag
        from lidarflow.predict import Predictor

        predictor = Predictor(None, spec, threads=None)  # the demo's --threads set already
        with progress_bar(len(recording), "writing predictions") as bar:
            predict_to_bag(
                recording, predictor, folder / "predictions.mcap", bar.update, source=bag
            )
        typer.echo(f"predictions for Foxglove: {output / 'predictions.mcap'}")


@dataclass(frozen=True)
class PredictOptions:
    """``predict``'s command line."""

    inputs: Annotated[
        list[Path], typer.Argument(help="Recordings (.npz) or bags/MCAP to predict on.")
    ]
    output: Annotated[
        Path,
        typer.Option(
            "--output",
            "-o",
            help="Bag to write: .bag (ROS 1), .mcap (MCAP file) or a new folder (ROS 2 bag); for "
            "several inputs a folder, one NAME.mcap in it per input.",
        ),
    ]
    topic: TopicOpt = None
    odom_topic: OdomOpt = None
    model: ModelOpt = None
    horizon: Annotated[
        int, typer.Option(help="Frames ahead to predict (predictions fed back).", min=1)
    ] = 1
    fixed_decision: Annotated[
        bool,
        typer.Option(
            "--fixed-decision",
            help="Decide with the model's fixed decision offsets even where it chooses them "
            "online as it streams (the bundled model does).",
        ),
    ] = False
    combine: CombineOpt = False
    no_combine: NoCombineOpt = False
    learn: LearnOpt = False
    grid: ModelGridOpt = None
    res: ModelResOpt = None
    moving_threshold: MovingOpt = None
    topics: Annotated[
        str,
        typer.Option(
            "--topics",
            help="What to write, comma-separated: input, occupancy, predicted, decided, moving, "
            "flow, planner_grid; 'default' is all but flow and planner_grid, 'all' everything "
            "(e.g. default,flow).",
        ),
    ] = "default"
    planner_grid: Annotated[
        bool,
        typer.Option(
            "--planner-grid",
            help="Also write /lidarflow/planner_grid: per cell the largest predicted probability "
            "over the --horizon frames, in the scan's frame, for a local planner.",
        ),
    ] = False
    force: ForceOpt = False
    threads: ThreadsOpt = DEFAULT_THREADS
    jobs: JobsOpt = 1


@app.command()
@command_options(PredictOptions)
def predict(options: PredictOptions) -> None:
    """Write the input bag's messages, unchanged, plus per scan the predicted next map
    (OccupancyGrid in the scan's frame, stamped with the time it predicts, for RViz/Foxglove),
    the current map and, from a flow model (not the bundled one), the moving cells to a new bag
    (compressed chunks). --topics adds a flow model's flow (32FC2 and rgb8 colour-wheel
    images) or leaves groups out.

    An ego-motion model gets the recording's poses; without poses the bundled model matches
    the motion from the scans."""
    from lidarflow.cli.per_input import PredictSettings, PredictTask
    from lidarflow.outputs.rosout import output_kind
    from lidarflow.predict.moving import MOVING_THRESHOLD

    o = options
    groups = _topic_groups(o.topics) | ({"planner_grid"} if o.planner_grid else set())
    outputs = _outputs(o.inputs, o.output)
    for out in outputs:
        folder = output_kind(out) == "ros2"  # a ROS 2 bag is a folder
        refuse_existing(out, force=o.force, folder=folder, inputs=[*o.inputs, o.model])
    threshold = MOVING_THRESHOLD if o.moving_threshold is None else o.moving_threshold
    settings = PredictSettings(
        o.topic, o.odom_topic, o.model, model_grid(o.model, o.grid, o.res), o.horizon,
        o.threads, threshold, False if o.fixed_decision else None, groups, o.force,
        combine_choice(o.combine, o.no_combine),
        o.learn,
    )  # fmt: skip
    tasks = [PredictTask(i, out, settings) for i, out in zip(o.inputs, outputs, strict=True)]
    done = _predict_all(tasks, o)
    if "flow" in groups and any(d.value is not None and not d.value.has_flow for d in done):
        # A head-only model (the bundled one) has no flow to write: say why it is absent.
        typer.echo(
            "note: this model has no flow network, so no flow or moving cells were written; "
            "pass --model of a flow model (e.g. one trained with --recipe blurred) for them"
        )
    if any(d.error is not None for d in done):  # each said in its one line above
        raise typer.Exit(1)


def _predict_all(tasks: list[Any], options: PredictOptions) -> list[Any]:
    """Each task's outcome, said as it is in: one input in this process (its errors the
    command's), several in ``--jobs`` workers into the folder ``-o``."""
    from lidarflow.cli.jobs import Outcome, resolve_jobs, run_jobs
    from lidarflow.cli.per_input import predict_input

    if len(tasks) == 1:
        done = Outcome(0, predict_input(tasks[0]))
        _say_written(tasks[0], done)
        return [done]
    options.output.mkdir(exist_ok=True)  # each output in it is written whole or not at all

    def said(outcome: Outcome) -> None:  # in input order, as each is in
        if outcome.notes:
            typer.echo(outcome.notes, err=True, nl=False)
        if outcome.error is not None:
            typer.echo(f"lidarflow: error: {outcome.error}", err=True)
        else:
            _say_written(tasks[outcome.index], outcome)

    workers = resolve_jobs(options.jobs, len(tasks))
    desc = f"predicting {len(tasks)} inputs, {workers} at once"
    names = [str(i) for i in options.inputs]
    return run_jobs(predict_input, tasks, names, workers, options.threads, desc, said)


def _outputs(inputs: list[Path], output: Path) -> list[Path]:
    """Where ``predict`` writes each input: ``output`` for one; for several, ``STEM.mcap`` per
    input in the folder ``output`` (numbered where two share a stem)."""
    if len(inputs) == 1:
        return [output]
    from lidarflow.evaluate.evaluation import unique_stems
    from lidarflow.outputs.rosout import output_kind

    if output_kind(output) != "ros2" or output.is_file():
        raise typer.BadParameter(
            f"{output}: for several inputs -o names a folder (one NAME.mcap per input in it)",
            param_hint="-o",
        )
    return [output / f"{stem}.mcap" for stem in unique_stems([str(i) for i in inputs])]


def _say_written(task: Any, outcome: Any) -> None:
    counts = outcome.value.counts
    typer.echo(f"wrote {task.output}: " + ", ".join(f"{t} x{n}" for t, n in counts.items()))


def _topic_groups(text: str) -> frozenset[str]:
    """``--topics``: the groups named, ``default`` and ``all`` spelled out."""
    from lidarflow.outputs.job import DEFAULT_TOPICS, TOPIC_GROUPS

    groups: set[str] = set()
    for name in (n.strip().lower() for n in text.split(",")):
        if name == "default":
            groups |= DEFAULT_TOPICS
        elif name == "all":
            groups |= set(TOPIC_GROUPS)
        elif name in TOPIC_GROUPS:
            groups.add(name)
        else:
            choices = ", ".join((*TOPIC_GROUPS, "default", "all"))
            raise typer.BadParameter(f"{name!r} is none of {choices}", param_hint="--topics")
    return frozenset(groups)


@dataclass(frozen=True)
class ExportOptions:
    """``export``'s command line."""

    output: Annotated[
        Path | None, typer.Option("--output", "-o", help="ONNX file to write (required).")
    ] = None
    model: ExportModelOpt = None
    grid: ModelGridOpt = None
    res: ModelResOpt = None
    int8: Annotated[
        bool,
        typer.Option(
            "--int8",
            help="Quantize the convolutions to int8 (static, per-channel; ~1.4x faster on CPU, "
            "F1 within ~0.001), ranges calibrated by streaming --calibration through the model.",
        ),
    ] = False
    calibration: Annotated[
        Path | None,
        typer.Option(
            "--calibration",
            help="Recording or bag whose maps calibrate --int8 (default: the bundled sample "
            "bag; use one from your own sensor).",
        ),
    ] = None
    topic: TopicOpt = None
    force: ForceOpt = False
    threads: ThreadsOpt = DEFAULT_THREADS
    onnx: Annotated[Path | None, typer.Option("--onnx", hidden=True)] = None


@app.command()
@command_options(ExportOptions)
def export(options: ExportOptions) -> None:
    """Export one streaming step (hidden state as explicit inputs/outputs) to ONNX, for
    onnxruntime inference without PyTorch (`lidarflow predict --model X.onnx`)."""
    from lidarflow.atomic import atomic_path
    from lidarflow.models.presets import resolve_model
    from lidarflow.outputs.export import export_onnx
    from lidarflow.predict.backends import recorded_grid
    from lidarflow.predict.decision import DecisionPolicy

    o = options
    output = _onnx_output(o)
    refuse_existing(output, force=o.force, inputs=[o.model, o.calibration])
    use_threads(o.threads)
    net, card = resolve_model(o.model)
    policy = DecisionPolicy.from_record(card.get("decision"))  # travels with the file
    spec = completed_grid(recorded_grid(card), o.grid, o.res)
    size = f"{spec.height}x{spec.width} grid of {spec.res:g} m"
    if o.int8:
        calibrated = _export_int8(net, policy, spec, output, o)
        typer.echo(f"wrote {output} ({card.get('model')}, {size}, {calibrated})")
        return
    with atomic_path(output) as tmp:  # whole or not at all
        export_onnx(net, tmp, spec.height, spec.width, spec.res, policy)
    typer.echo(f"wrote {output} ({card.get('model')}, {size})")


def _onnx_output(options: ExportOptions) -> Path:
    """The file ``-o`` (or ``--onnx``, its old name) names; a usage error where the flags
    contradict or name none."""
    if options.calibration is not None and not options.int8:
        # else a float model is written and the user believes it calibrated and quantized
        raise typer.BadParameter(
            "--calibration calibrates --int8; add --int8 or drop --calibration",
            param_hint="--calibration",
        )
    output = options.output
    if options.onnx is not None:  # the spelling before -o/--output, kept working
        if output is not None:
            raise typer.BadParameter("give -o/--output once (--onnx is its old name)")
        typer.echo("note: --onnx is now -o/--output", err=True)
        output = options.onnx
    if output is None:
        raise typer.BadParameter("name the ONNX file to write: -o FILE.onnx", param_hint="-o")
    return output


def _export_int8(net: Any, policy: Any, spec: Any, output: Path, options: ExportOptions) -> str:
    """Write ``net`` to ``output`` with int8 convolutions calibrated on ``--calibration``'s
    maps (default: the bundled sample bag); returns what it was calibrated on."""
    import tempfile

    from lidarflow.data import sample_bag_path
    from lidarflow.outputs.export import export_onnx
    from lidarflow.outputs.quantize import quantize_onnx
    from lidarflow.scan import takes_subcell

    source = options.calibration or sample_bag_path()
    recording = load_input(source, options.topic)
    maps = recording.stacked_maps(spec, subcell=takes_subcell(net.capabilities.input_channels))
    with tempfile.TemporaryDirectory() as tmp:
        float_path = export_onnx(
            net, Path(tmp) / "float.onnx", spec.height, spec.width, spec.res, policy
        )
        quantize_onnx(float_path, output, maps)
    return f"int8 convolutions calibrated on {len(maps)} frames of {source.name}"
