"""The ``lidarflow`` command: argument parsing only.

Every sub-command turns lidarflow errors into one line on stderr and exit status 1; usage errors
exit with 2 (typer/click's convention). Set ``LIDARFLOW_DEBUG=1`` to see tracebacks.
"""

from __future__ import annotations

import dataclasses
import inspect
import json
import os
import sys
from pathlib import Path
from typing import Annotated, Any

import typer

from lidarflow.errors import LidarflowError

app = typer.Typer(
    name="lidarflow",
    help=(
        "Predict the next 2-D LiDAR occupancy map by estimating motion flow (LiDAR-FlowNet).\n\n"
        "Inputs may be recordings (.npz from `lidarflow convert`) or bags directly: ROS 1 .bag "
        "(or .bag.zip), ROS 2 bag folders (sqlite3/mcap) and .mcap files (ROS 2 messages, or "
        "ROS 1 messages as `mcap convert` leaves a ROS 1 bag)."
    ),
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    context_settings={"help_option_names": ["-h", "--help"]},
)

TopicOpt = Annotated[
    str | None,
    typer.Option("--topic", "-t", help="LaserScan topic (needed only when the bag has several)."),
]
OdomOpt = Annotated[
    str | None,
    typer.Option(
        "--odom-topic",
        help="Odometry (nav_msgs/Odometry or PoseStamped) topic for sensor poses; by default the "
        "bag's only Odometry topic, if it has one. The base's poses are moved to the scanner "
        "by the bag's TF (base -> scan frame) when it has it.",
    ),
]
GridOpt = Annotated[int, typer.Option("--grid", help="Map size in cells (square grid).", min=4)]
ResOpt = Annotated[float, typer.Option("--res", help="Cell size in metres.", min=1e-4)]
MovingOpt = Annotated[
    float | None,
    typer.Option(
        "--moving-threshold",
        help="Moving-object segmentation: an occupied cell is moving when its forward flow, less "
        "the background's (platform's) fitted motion, is longer than this many cells per frame "
        "(default 0.4, chosen on simulated tuning data).",
        min=0.0,
    ),
]


def _progress(total: int | None, desc: str) -> Any:
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit="scan", disable=None, leave=False)


def _eval_progress(name: str, total: int) -> Any:
    return _progress(total, f"evaluating {Path(name).name}")


def _load(path: Path, topic: str | None = None, odom_topic: str | None = None) -> Any:
    from lidarflow.data import load_any

    with _progress(None, f"reading {path.name}") as bar:
        return load_any(path, topic=topic, odom_topic=odom_topic, progress=bar.update)


@app.command()
def convert(
    input: Annotated[
        Path, typer.Argument(help="Bag (.bag, .bag.zip), ROS 2 bag folder or .mcap.")
    ],
    output: Annotated[Path, typer.Option("--output", "-o", help="Recording to write (.npz).")],
    topic: TopicOpt = None,
    odom_topic: OdomOpt = None,
    grid: GridOpt = 100,
    res: ResOpt = 0.1,
) -> None:
    """Convert a LaserScan topic into a lidarflow recording (raw scans, stamps, poses).

    The raw ranges are kept, so maps can be rasterized later on any grid; --grid/--res only set
    the grid recorded as this recording's default and checked here by rasterizing every scan.
    """
    from lidarflow.scan import GridSpec

    recording = _load(input, topic, odom_topic)
    spec = GridSpec(grid, grid, res)
    recording.maps(spec)  # fail now, not in training, if any scan cannot be rasterized
    recording.meta["grid"] = spec.to_dict()
    path = recording.save(output)
    poses = "with poses" if recording.has_poses else "no poses"
    no_mount = "sensor_mount" in recording.meta and recording.meta["sensor_mount"] is None
    if recording.has_poses and no_mount:
        poses += " (the odometry's own frame: the bag has no TF to the scanner)"
    typer.echo(
        f"wrote {path}: {len(recording)} scans from {recording.meta['topic']} at "
        f"{recording.frame_rate:.2f} Hz, {poses}"
    )


@app.command()
def info(
    input: Annotated[Path, typer.Argument(help="Recording (.npz) or bag/MCAP.")],
    topic: TopicOpt = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON instead of text.")] = False,
) -> None:
    """List topics (bags), scan counts, frame rate, field of view, range limits, invalid beams
    and time gaps."""
    from lidarflow.data import describe_recording, list_topics
    from lidarflow.data.sources import is_recording_file

    report: dict[str, Any] = {"path": str(input)}
    if not is_recording_file(input):
        topics = list_topics(input)
        report["topics"] = [
            {"topic": t.topic, "type": t.msgtype, "count": t.count} for t in topics
        ]
        scan_topics = [t.topic for t in topics if t.msgtype.endswith("LaserScan")]
        if topic is None and len(scan_topics) != 1:
            report["scan_topics"] = scan_topics
            _print_info(report, as_json)
            if scan_topics:
                typer.echo("several LaserScan topics: name one with --topic for its details")
            return
    recording = _load(input, topic)
    report["topic"] = recording.meta.get("topic")
    report.update(describe_recording(recording))
    _print_info(report, as_json)


def _print_info(report: dict[str, Any], as_json: bool) -> None:
    if as_json:
        typer.echo(json.dumps(report, indent=2))
        return
    for key, value in report.items():
        if key == "topics":
            typer.echo("topics:")
            for t in value:
                typer.echo(f"  {t['topic']:<40} {t['type']:<40} {t['count']:>8}")
        elif key == "beams":
            typer.echo("beams: " + ", ".join(f"{k}={v}" for k, v in value.items()))
        elif key == "gaps":
            shown = ", ".join(
                f"{g['seconds']}s before frame {g['before_frame']}" for g in value[:10]
            )
            more = f" (+{len(value) - 10} more)" if len(value) > 10 else ""
            typer.echo(f"gaps: {len(value)}" + (f": {shown}{more}" if value else ""))
        else:
            typer.echo(f"{key}: {value}")


@app.command()
def show(
    recording: Annotated[Path, typer.Argument(help="Recording (.npz) or bag/MCAP.")],
    frame: Annotated[
        int, typer.Option("--frame", "-f", help="Frame index (negative counts from the end).")
    ] = 0,
    output: Annotated[Path, typer.Option("--output", "-o", help="PNG to write.")] = Path(
        "maps.png"
    ),
    topic: TopicOpt = None,
    grid: GridOpt = 100,
    res: ResOpt = 0.1,
    flow: Annotated[
        bool,
        typer.Option("--flow/--no-flow", help="Overlay ground-truth flow if the recording has it."),
    ] = True,
    flow_scale: Annotated[
        float, typer.Option("--flow-scale", help="Draw flow arrows N times longer.", min=0.0)
    ] = 1.0,
) -> None:
    """Draw the occupancy and visibility maps of one frame (sensor at the bottom middle).

    On a simulated recording the ground truth is overlaid: cells on moving objects in red, and
    the forward flow F^t (where each occupied cell of this frame goes in the next) as arrows."""
    from lidarflow.errors import RecordingError
    from lidarflow.scan import GridSpec
    from lidarflow.viz.maps import draw_maps

    rec = _load(recording, topic)
    if not -len(rec) <= frame < len(rec):
        raise RecordingError(f"{recording}: frame {frame} out of range (it has {len(rec)} frames)")
    index = frame % len(rec)
    spec = GridSpec(grid, grid, res)
    occ, vis = rec.maps(spec, index, index + 1)
    gt_flow = moving = None
    # Forward flow F^t lives on the occupied cells of O^t (design notes, section 3): it is the
    # one that belongs on this frame's map. (B^t lives on O^{t+1}'s cells.)
    if flow and rec.meta.get("simulated"):
        from lidarflow.sim import dense_flow

        _, forward = dense_flow(rec, index)
        if forward.shape[-2:] == spec.shape:
            gt_flow = forward
            moving = rec.extras.get("moving", [None] * len(rec))[index]
        else:
            typer.echo(f"note: ground truth is on a {forward.shape[-2:]} grid, not drawn here")
    title = f"{recording.name}  frame {index}/{len(rec)}  t={rec.stamps_ns[index] / 1e9:.3f}s"
    path = draw_maps(
        occ[0], vis[0], output, spec, title, flow=gt_flow, moving=moving, flow_scale=flow_scale
    )
    typer.echo(f"wrote {path}")


@app.command()
def demo(
    output: Annotated[
        Path, typer.Option("--output", "-o", help="Folder for the demo's outputs.")
    ] = Path("demo_out"),
) -> None:
    """Run the main job on the bundled sample recording: convert it, draw a frame, predict
    every next map with the bundled model, score it beside the baselines (report.json and an
    HTML page), and write the predictions as an MCAP file for Foxglove."""
    from lidarflow.data import SAMPLE_TOPIC, describe_recording, sample_bag_path
    from lidarflow.evaluate.report import format_table
    from lidarflow.models.presets import bundled_model_dir
    from lidarflow.scan import GridSpec
    from lidarflow.viz.evaluation import evaluate_and_report
    from lidarflow.viz.maps import draw_maps

    output.mkdir(parents=True, exist_ok=True)
    bag = sample_bag_path()
    recording = _load(bag, SAMPLE_TOPIC)
    rec_path = recording.save(output / "sample.npz")
    summary = describe_recording(recording)
    typer.echo(
        f"sample: {bag.name} ({summary['scans']} scans, {summary['frame_rate_hz']} Hz, "
        f"{summary['beams_per_scan']} beams) -> {rec_path}"
    )
    spec = GridSpec()
    frame = len(recording) // 2
    occ, vis = recording.maps(spec, frame, frame + 1)
    png = draw_maps(occ[0], vis[0], output / "maps.png", spec, title=f"{bag.name} frame {frame}")
    typer.echo(f"maps of frame {frame}: {png}")
    has_model = (bundled_model_dir() / "model.safetensors").exists()
    if not has_model:
        typer.echo("no bundled model in this installation: scoring the baselines only")
    methods, config = _methods_and_config(
        [None] if has_model else [], with_poses=recording.has_poses
    )
    config.update({"warmup": 10, "grid": spec.to_dict()})
    report = evaluate_and_report(
        [(str(bag), recording)], methods, spec, 10, config, output / "report", 60, _eval_progress
    )
    (output / "results.json").write_text(json.dumps(report, indent=2))
    entry = report["recordings"][0]
    title = f"next-map prediction, {entry['frames_evaluated']} frames"
    typer.echo(format_table(entry["methods"], title))
    typer.echo(f"results: {output / 'results.json'}; report: {output / 'report' / 'index.html'}")
    if has_model:
        from lidarflow.predict import Predictor
        from lidarflow.predict.job import predict_to_bag

        target = output / "predictions.mcap"
        if target.exists():
            target.unlink()
        predictor = Predictor(None, spec)
        with _progress(len(recording), "writing predictions") as bar:
            predict_to_bag(recording, predictor, target, bar.update)
        typer.echo(f"predictions for Foxglove: {target}")


def _methods_and_config(
    sources: list[Path | None],
    ta_window: int = 5,
    ta_threshold: float = 0.4,
    moving_threshold: float | None = None,
    ego_oracle: bool = False,
    with_poses: bool = True,
    online: bool = False,
    res: float = 0.1,
) -> tuple[list[Any], dict[str, Any]]:
    """The baselines plus one method per model source (``None``: the bundled model), and the
    configuration that describes them for the report. With an ego-motion model among them and
    recordings with poses (``with_poses``) the copy-last-moved-by-odometry baseline comes too
    (without poses it would be copy-last again); ``ego_oracle`` adds the variants that know the
    true next pose; ``online`` adds, for each model, the decision rule it was not built with:
    ``NAME_online`` (offsets chosen on the recording as it streams) or ``NAME_fixed``."""
    from lidarflow.evaluate.baselines import ConstantVelocity, CopyLast, TemporalAverage
    from lidarflow.evaluate.model_method import ModelMethod
    from lidarflow.evaluate.online import OnlineDecisionConfig
    from lidarflow.models.presets import resolve_model
    from lidarflow.models.streaming import StreamingModel
    from lidarflow.models.weights import describe_source
    from lidarflow.segmentation import MOVING_THRESHOLD

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
        method = ModelMethod(
            name, StreamingModel(net), moving_threshold, online_config=online_config, res=res
        )
        methods.append(method)
        models_used[name] = {k: card.get(k) for k in ("model", "weights_path", "weights_sha256")}
        if method.uses_motion and ego_oracle:
            methods.append(
                ModelMethod(name + "_oracle", StreamingModel(net), oracle=True, res=res)
            )
        if online:  # the other decision rule beside the model's own
            wants_online = method.online is not None
            methods.append(
                ModelMethod(
                    name + ("_fixed" if wants_online else "_online"),
                    StreamingModel(net),
                    moving_threshold,
                    online=not wants_online,
                    online_config=online_config,
                    res=res,
                )
            )
    if with_poses and any(getattr(m, "uses_motion", False) for m in methods):
        from lidarflow.evaluate.ego import CopyLastEgo

        methods[3:3] = [CopyLastEgo()] + ([CopyLastEgo(oracle=True)] if ego_oracle else [])
    config = {
        "threshold": 0.4,
        "temporal_average": {"window": ta_window, "threshold": ta_threshold},
        "constant_velocity": "best integer rigid shift (radius 3 cells) of the last two maps",
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
    if any(getattr(m, "uses_motion", False) for m in methods):
        config["ego_motion"] = (
            "models built with ego_motion get the recordings' poses (odometry); the motion to "
            "the next frame is the last one again (constant velocity, causal); *_oracle* "
            "variants use the true next pose instead; copy_last_ego moves the last map by it; "
            "on a recording without poses, models built with poses_optional (the head recipe's, "
            "the bundled one) get the motion matched from the scans (lidarflow.data.scanmatch; "
            "uncompensated where no match counts) and copy_last_ego is not scored"
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
            help="Trained model to evaluate beside the baselines: a run folder from "
            "`lidarflow train`, a .safetensors file with its .json, or `bundled`. Repeat for "
            "several; default: the bundled model.",
        ),
    ] = None,
    json_out: Annotated[
        Path | None, typer.Option("--json", help="Write the full report (JSON) here.")
    ] = None,
    report_dir: Annotated[
        Path | None,
        typer.Option(
            "--report",
            help="Folder for a self-contained HTML report (index.html) with PR curves and "
            "overlay GIFs (truth green, prediction red, both yellow), plus report.json.",
        ),
    ] = None,
    gif_frames: Annotated[
        int, typer.Option(help="Frames per overlay GIF in the report.", min=1)
    ] = 100,
    warmup: Annotated[
        int, typer.Option(help="Frames per recording that only warm the state up.", min=0)
    ] = 10,
    ta_window: Annotated[
        int, typer.Option(help="Temporal-average baseline: frames averaged.", min=1)
    ] = 5,
    ta_threshold: Annotated[
        float, typer.Option(help="Temporal-average baseline: occupied when mean >= this.")
    ] = 0.4,
    ego_oracle: Annotated[
        bool,
        typer.Option(
            "--ego-oracle",
            help="For ego-motion models: also score the variant told the true next pose (an "
            "upper bound; at run time only poses up to now are known).",
        ),
    ] = False,
    horizon: Annotated[
        int,
        typer.Option(
            min=1,
            help="Also score F1 1..K frames ahead (models roll forward on their own "
            "predictions, as `predict --horizon`; copy-last beside them); JSON key horizon_f1.",
        ),
    ] = 1,
    online_decision: Annotated[
        bool,
        typer.Option(
            "--online-decision",
            help="Score each occupancy-head model both ways: with its fixed decision offsets and "
            "with offsets chosen online (every frame, the pair of offsets, for the cells occupied "
            "/ free in the last map moved by the model's flow, that would have beaten the three "
            "baselines by the most on the frames so far; past frames only). The one the model "
            "was not built with is NAME_online or NAME_fixed.",
        ),
    ] = False,
    grid: GridOpt = 100,
    res: ResOpt = 0.1,
    moving_threshold: MovingOpt = None,
) -> None:
    """Score next-map prediction on each recording, streaming (one step per frame, state
    carried across the recording), with F1 at 0.4, precision, recall, average precision and
    changed-cell F1, for the baselines copy-last, temporal average and constant velocity and
    for every --model given (and flow end-point error where the recording has ground truth).

    A second table gives the calibration of every method's probabilities (expected calibration
    error over bins of 0.1 on all cells, ece_active on the cells predicted >= 0.1, and Brier
    score; lower is better) and, for flow models on simulated recordings, moving-object
    segmentation (IoU, precision, recall of the moving cells against the simulator's truth).
    The JSON has them per method under "calibration" (with the reliability-diagram bins) and
    "segmentation"; --report draws the reliability diagram and the moving cells.

    A model that compensates ego motion (the bundled one, the default recipe's, --ego-motion)
    gets each recording's poses (odometry) and the copy_last_ego baseline (the last map moved by
    the odometry) is scored beside it; on a recording without poses a model built with
    poses_optional (the bundled one, the default recipe's) takes the motion matched from the scans
    instead, any other is refused. Such a model also takes the scans' motion where the poses
    disagree with the scans (a base's odometry read as the scanner's).

    A model built with online_decision (the bundled one, the default recipe's) chooses its
    decision offsets as the recording streams, from the frames already seen; --online-decision
    scores every occupancy-head model both ways."""
    from lidarflow.evaluate.report import format_table, format_uncertainty_table
    from lidarflow.scan import GridSpec
    from lidarflow.viz.evaluation import evaluate_and_report

    spec = GridSpec(grid, grid, res)
    named = [(str(path), _load(path, topic, odom_topic)) for path in inputs]
    with_poses = any(recording.has_poses for _, recording in named)
    methods, config = _methods_and_config(
        list(model or []),
        ta_window,
        ta_threshold,
        moving_threshold,
        ego_oracle,
        with_poses,
        online_decision,
        spec.res,
    )
    config.update({"warmup": warmup, "grid": spec.to_dict()})
    report = evaluate_and_report(
        named, methods, spec, warmup, config, report_dir, gif_frames, _eval_progress
    )
    if horizon > 1:
        _add_horizon_scores(report, named, methods, spec, warmup, horizon)
    for entry in report["recordings"]:
        title = f"{entry['path']} ({entry['frames_evaluated']} frames)"
        typer.echo(format_table(entry["methods"], title) + "\n")
        if "horizon_f1" in entry:
            typer.echo(_format_horizon(entry["horizon_f1"]) + "\n")
        extra = format_uncertainty_table(entry["methods"], "calibration and moving segmentation")
        if extra:
            typer.echo(extra + "\n")
    if len(report["recordings"]) > 1:
        typer.echo(format_table(report["overall"], "overall (micro-averaged)"))
        extra = format_uncertainty_table(report["overall"], "overall calibration and segmentation")
        if extra:
            typer.echo(extra)
    if json_out is not None:
        json_out.parent.mkdir(parents=True, exist_ok=True)
        json_out.write_text(json.dumps(report, indent=2))
        typer.echo(f"wrote {json_out}")
    if report_dir is not None:
        typer.echo(f"wrote {report_dir / 'index.html'}")


def _add_horizon_scores(
    report: dict[str, Any],
    named: list[tuple[str, Any]],
    methods: list[Any],
    spec: Any,
    warmup: int,
    horizon: int,
) -> None:
    from lidarflow.data.scanalign import recording_points
    from lidarflow.evaluate.ego import recording_motions
    from lidarflow.evaluate.horizon import horizon_f1
    from lidarflow.scan import takes_subcell

    # one roll-out per model (an oracle variant has no roll-out of its own)
    streamed = [m for m in methods if hasattr(m, "stream") and not getattr(m, "oracle", False)]
    models = {m.name: m.stream.model for m in streamed}
    decisions = {m.name: m.online for m in streamed if m.online is not None}
    for entry, (name, recording) in zip(report["recordings"], named, strict=True):
        occupancy, visibility = recording.maps(spec)
        motions = recording_motions(recording, spec, streamed, occupancy)
        total = len(models) * max(0, len(occupancy) - horizon)
        with _progress(total, f"horizon {horizon}, {Path(name).name}") as bar:
            # Only odometry is replaced by the scans' motion; scan motions are only checked.
            with_returns = motions is not None and recording.has_poses
            returns = recording_points(recording) if with_returns else None
            wants = any(takes_subcell(model.input_channels) for model in models.values())
            entry["horizon_f1"] = horizon_f1(
                occupancy, visibility, models, horizon, warmup, bar.update, motions, decisions,
                returns, recording.has_poses, spec.res,
                recording.subcell_maps(spec) if wants else None,
            )  # fmt: skip


def _format_horizon(scores: dict[str, list[float]]) -> str:
    k = len(next(iter(scores.values())))
    lines = ["F1 per horizon step     " + "".join(f"{f'k={i + 1}':>10}" for i in range(k))]
    for name, values in scores.items():
        lines.append(f"{name:<24}" + "".join(f"{v:>10.4f}" for v in values))
    return "\n".join(lines)


ModelOpt = Annotated[
    Path | None,
    typer.Option(
        "--model",
        "-m",
        help="Run folder from `lidarflow train`, a .safetensors file, an .onnx file, or "
        "`bundled` (the default: the bundled pretrained model).",
    ),
]


@app.command()
def predict(
    input: Annotated[Path, typer.Argument(help="Recording (.npz) or bag/MCAP to predict on.")],
    output: Annotated[
        Path,
        typer.Option(
            "--output",
            "-o",
            help="Bag to write: .bag (ROS 1), .mcap (MCAP file) or a new folder (ROS 2 bag).",
        ),
    ],
    topic: TopicOpt = None,
    odom_topic: OdomOpt = None,
    model: ModelOpt = None,
    horizon: Annotated[
        int, typer.Option(help="Frames ahead to predict (predictions fed back).", min=1)
    ] = 1,
    fixed_decision: Annotated[
        bool,
        typer.Option(
            "--fixed-decision",
            help="Decide with the model's fixed decision offsets even where it chooses them "
            "online as it streams (the bundled model does).",
        ),
    ] = False,
    grid: GridOpt = 100,
    res: ResOpt = 0.1,
    moving_threshold: MovingOpt = None,
) -> None:
    """Write the input scans plus, per scan, the predicted next map (nav_msgs/OccupancyGrid in
    the scan's frame, ready for RViz/Foxglove), the flow (32FC2 images) and the moving cells of
    the current map (/lidarflow/moving, OccupancyGrid: 100 moving, 0 not, -1 unseen) to a new
    bag.

    A model that compensates ego motion gets the recording's poses (odometry) with every scan;
    on a recording without poses a model built with poses_optional (the bundled one, the
    default recipe's) takes the motion matched from the scans instead (and where the poses
    disagree with the scans), any other is refused."""
    from lidarflow.predict import Predictor
    from lidarflow.predict.job import predict_to_bag
    from lidarflow.scan import GridSpec

    recording = _load(input, topic, odom_topic)
    from lidarflow.segmentation import MOVING_THRESHOLD

    threshold = MOVING_THRESHOLD if moving_threshold is None else moving_threshold
    predictor = Predictor(
        model,
        GridSpec(grid, grid, res),
        horizon=horizon,
        moving_threshold=threshold,
        online_decision=False if fixed_decision else None,
    )
    with _progress(len(recording), f"predicting {input.name}") as bar:
        counts = predict_to_bag(recording, predictor, output, bar.update)
    typer.echo(f"wrote {output}: " + ", ".join(f"{t} x{n}" for t, n in counts.items()))


@app.command()
def export(
    onnx: Annotated[Path, typer.Option("--onnx", help="ONNX file to write.")],
    model: ModelOpt = None,
    grid: GridOpt = 100,
    res: ResOpt = 0.1,
    int8: Annotated[
        bool,
        typer.Option(
            "--int8",
            help="Quantize the convolutions to int8 (static, per-channel; ~1.4x faster on CPU, "
            "F1 within ~0.001), ranges calibrated by streaming --calibration through the model.",
        ),
    ] = False,
    calibration: Annotated[
        Path | None,
        typer.Option(
            "--calibration",
            help="Recording or bag whose maps calibrate --int8 (default: the bundled sample "
            "bag; use one from your own sensor).",
        ),
    ] = None,
    topic: TopicOpt = None,
) -> None:
    """Export one streaming step (hidden state as explicit inputs/outputs) to ONNX, for
    onnxruntime inference without PyTorch (`lidarflow predict --model X.onnx`)."""
    import tempfile

    from lidarflow.models.presets import resolve_model
    from lidarflow.predict.export import export_onnx
    from lidarflow.scan import GridSpec, takes_subcell

    net, card = resolve_model(model)
    if not int8:
        path = export_onnx(net, onnx, grid, grid)
        typer.echo(f"wrote {path} ({card.get('model')}, {grid}x{grid} grid)")
        return

    from lidarflow.data import sample_bag_path
    from lidarflow.predict.quantize import quantize_onnx

    source = calibration or sample_bag_path()
    recording = _load(source, topic)
    spec = GridSpec(grid, grid, res)
    maps = recording.stacked_maps(spec, subcell=takes_subcell(net.input_channels))
    with tempfile.TemporaryDirectory() as tmp:
        float_path = export_onnx(net, Path(tmp) / "float.onnx", grid, grid)
        path = quantize_onnx(float_path, onnx, maps)
    typer.echo(
        f"wrote {path} ({card.get('model')}, {grid}x{grid} grid, int8 convolutions calibrated "
        f"on {len(maps)} frames of {source.name})"
    )


@app.command(
    help="Train LiDAR-FlowNet or the DeepTracking baseline, self-supervised, on recordings and "
    "bags.\n\n"
    "The default recipe for LiDAR-FlowNet is head, the best measured on recordings it never "
    "saw (docs/results/accuracy/loo): the bundled flow network (or --init RUN) with an "
    "occupancy head fitted to your recordings, about 8 CPU-minutes. --recipe paper is the "
    "paper's (and the default for deeptracking and --ego-motion): sequences of 20 frames, 10 "
    "warm-up frames, Gaussian size 9 -> 1 (minus 2 every 25 epochs), batch 32, Adam at lr 0.01 "
    "halved every 25 epochs, 200 epochs. Settings come from the recipe, then --config, then "
    "these flags, then --set.\n\n"
    "The run directory gets config.json, metrics.csv/.jsonl (losses, validation F1 against "
    "copy-last, flow EPE on simulated data), a checkpoint every epoch (a killed run loses at most "
    "one), best/last weights, and model.safetensors + model.json for the other commands. "
    "Runs unchanged under torchrun (DDP: gloo on CPU, nccl on GPU).",
    epilog="Examples:\n\n"
    "lidarflow train real.npz 'sim/*.npz' --mix 0.5 -o runs/a  (half of each epoch from each)\n\n"
    "lidarflow train a.bag --recipe blurred --set loss.smoothness=0.1 -o runs/b\n\n"
    "lidarflow train my_robot.bag -o runs/h  (the bundled flow, a head fitted to your robot)\n\n"
    "lidarflow train 'sim/*.npz' my_robot.bag --recipe blurred -o runs/flow; lidarflow train "
    "my_robot.bag --init runs/flow -o runs/h  (your own flow network first)\n\n"
    "lidarflow train drive.npz --ego-motion -o runs/e  (odometry-compensated; needs poses)\n\n"
    "lidarflow train --resume runs/a --epochs 300  (continue exactly, then extend)\n\n"
    "torchrun --nproc_per_node 2 -m lidarflow.cli train DATA... -o runs/c",
)
def train(
    data: Annotated[
        list[str] | None,
        typer.Argument(
            help="Training data sources: recordings (.npz), bags / ROS 2 bag folders / .mcap "
            "(converted on the fly), folders of .npz, or quoted glob patterns. Each argument is "
            "one source for --mix.",
            show_default=False,
        ),
    ] = None,
    output: Annotated[
        Path | None, typer.Option("--output", "-o", help="Run directory to create.")
    ] = None,
    model: Annotated[
        str | None, typer.Option("--model", "-m", help="flownet (LiDAR-FlowNet) or deeptracking.")
    ] = None,
    ego_motion: Annotated[
        bool,
        typer.Option(
            "--ego-motion",
            help="Ego-motion compensation: before each step the recurrent state is warped "
            "rigidly into the current sensor frame by the odometry (the recordings' poses; "
            "`convert --odom-topic`, or the simulator's), and the prediction is moved into the "
            "next frame at constant velocity, so the net only explains the world's motion. "
            "Same as --set model.kwargs.ego_motion=true. evaluate/predict then use the poses "
            "of their recordings by themselves.",
        ),
    ] = False,
    recipe: Annotated[
        str | None,
        typer.Option(
            help="Named preset: paper (the loss exactly as published), blurred (both "
            "sides of the loss blurred), residual (blurred + occupancy head trained by "
            "cross-entropy; sized for ~1 CPU-hour) or head (the default: an occupancy "
            "head with the constant-velocity input trained on a frozen flow network, --init, "
            "by default the bundled one; ~8 CPU-minutes; docs/results/accuracy/loo)."
        ),
    ] = None,
    config: Annotated[
        Path | None,
        typer.Option("--config", help="JSON or TOML file of settings (partial is fine); "
                     "a run's config.json works."),
    ] = None,
    init: Annotated[
        str | None,
        typer.Option("--init", help="Start from these weights (run folder, weights file, or "
                     "'bundled') instead of from scratch: fine-tuning. A flow-only "
                     "model can start one with an occupancy head (the head starts fresh)."),
    ] = None,
    resume: Annotated[
        Path | None,
        typer.Option(help="Continue the run in this directory exactly (weights, optimizer, "
                     "schedules, RNG, data order); --epochs may extend it."),
    ] = None,
    epochs: Annotated[int | None, typer.Option(help="Epochs (paper: 200).", min=1)] = None,
    batch_size: Annotated[
        int | None, typer.Option(help="Sequences per batch (default 32).", min=1)
    ] = None,
    lr: Annotated[
        float | None, typer.Option(help="Initial learning rate (default 0.01).")
    ] = None,
    optimizer: Annotated[str | None, typer.Option(help="adam (default), adamw or sgd.")] = None,
    grad_clip: Annotated[
        float | None, typer.Option(help="Clip the global gradient norm to this (0: off, default).")
    ] = None,
    seq_len: Annotated[
        int | None, typer.Option(help="Frames per sequence (default 20).", min=2)
    ] = None,
    warmup: Annotated[
        int | None, typer.Option(help="Frames that only warm up the state (default 10).", min=0)
    ] = None,
    no_gaussian: Annotated[
        bool, typer.Option("--no-gaussian", help="Ablation: no Gaussian filter in the loss.")
    ] = False,
    mix: Annotated[
        list[float] | None,
        typer.Option(help="Sampling weight per source, repeated (--mix 3 --mix 1); with two "
                     "sources one value is the first's fraction."),
    ] = None,
    val: Annotated[
        list[str] | None,
        typer.Option("--val", help="Validation recordings (repeatable); then nothing is held out."),
    ] = None,
    val_fraction: Annotated[
        float | None, typer.Option(help="Share held out for validation (default 0.1).")
    ] = None,
    val_split: Annotated[
        str | None,
        typer.Option(help="tail: the last frames of each recording (default); recordings: "
                     "whole recordings."),
    ] = None,
    topic: TopicOpt = None,
    grid: Annotated[
        int | None, typer.Option("--grid", help="Map size in cells (default 100).")
    ] = None,
    res: Annotated[
        float | None, typer.Option("--res", help="Cell size in metres (default 0.1).")
    ] = None,
    device: Annotated[str | None, typer.Option(help="auto (CUDA if available), cpu, cuda.")] = None,
    amp: Annotated[str | None, typer.Option(help="none (fp32 reference) or bf16 autocast.")] = None,
    compile: Annotated[
        bool,
        typer.Option("--compile", help="torch.compile each ConvGRU cell (pays on long runs; "
                     "--set runtime.compile=step compiles the whole step)."),
    ] = False,
    channels_last: Annotated[
        bool, typer.Option("--channels-last", help="Channels-last memory format.")
    ] = False,
    threads: Annotated[int | None, typer.Option(help="Torch CPU threads (0: default).")] = None,
    seed: Annotated[int | None, typer.Option(help="Random seed (default 0).")] = None,
    set_: Annotated[
        list[str] | None,
        typer.Option("--set", help="Any setting as section.field=value, e.g. optim.lr=0.003, "
                     "loss.smoothness=0.1, data.stride=5 (repeatable; applied last)."),
    ] = None,
) -> None:
    """``lidarflow train``: the help text above says it all (kept there for --help)."""
    import dataclasses

    from lidarflow.errors import TrainError
    from lidarflow.train.config import (
        build_config,
        config_from_dict,
        default_recipe,
        load_config_file,
    )
    from lidarflow.train.loop import train as run_training

    flags = {
        "model.name": model,
        "model.init": init if init in (None, "bundled") else os.path.abspath(init),
        "optim.epochs": epochs,
        "optim.batch_size": batch_size,
        "optim.lr": lr,
        "optim.name": optimizer,
        "optim.grad_clip": grad_clip,
        "data.seq_len": seq_len,
        "data.warmup": warmup,
        "schedule.gaussian": False if no_gaussian else None,
        "data.mix": mix or None,
        "data.val_sources": [os.path.abspath(v) for v in val] if val else None,
        "data.val_fraction": val_fraction,
        "data.val_split": val_split,
        "data.topic": topic,
        "data.grid": grid,
        "data.res": res,
        "runtime.device": device,
        "runtime.amp": amp,
        "runtime.compile": "cells" if compile else None,
        "runtime.channels_last": True if channels_last else None,
        "runtime.threads": threads,
        "runtime.seed": seed,
    }
    if resume is not None:
        if output is not None and output.resolve() != resume.resolve():
            raise typer.BadParameter(
                f"--resume {resume} and -o {output} name different runs; give one",
                param_hint="--resume",
            )
        # how the run executes may change (device, amp, threads...), not what it computes
        free = {"optim.epochs"} | {k for k in flags if k.startswith("runtime.")} - {"runtime.seed"}
        changed = [k for k, v in flags.items() if v is not None and k not in free]
        changed += ["--ego-motion"] if ego_motion else []
        if changed or recipe or config or set_:
            raise typer.BadParameter(
                "a resumed run keeps its config (only --epochs and runtime options may change); "
                f"drop {', '.join(changed) or '--recipe/--config/--set'} or start a new run",
                param_hint="--resume",
            )
        saved = config_from_dict(load_config_file(resume / "config.json"))
        if data and [os.path.abspath(d) for d in data] != saved.data.sources:
            raise TrainError(f"{resume} was trained on {saved.data.sources}, not {list(data)}")
        cfg = build_config(saved.recipe, resume / "config.json",
                           {k: v for k, v in flags.items() if k in free})
        run_dir = resume
    else:
        if output is None:
            raise typer.BadParameter(
                "name the run directory with -o RUN_DIR (or --resume RUN_DIR)", param_hint="-o"
            )
        if not data and config is None:
            raise typer.BadParameter("give training data: recordings or bags", param_hint="DATA")
        if data:  # absolute, so that --resume works from any folder (globs too)
            flags["data.sources"] = [os.path.abspath(d) for d in data]
        in_file = load_config_file(config) if config else {}
        if recipe is None and "recipe" not in in_file:
            named = model or in_file.get("model", {}).get("name")
            recipe = default_recipe(named, ego_motion)
        cfg = build_config(recipe, config, flags, set_ or ())
        if ego_motion:  # added to, not replacing, any other model kwargs
            kwargs = {**cfg.model.kwargs, "ego_motion": True}
            cfg = dataclasses.replace(cfg, model=dataclasses.replace(cfg.model, kwargs=kwargs))
        run_dir = output
    from tqdm import tqdm

    result = run_training(cfg.validate(), run_dir, resume=resume is not None, echo=tqdm.write)
    typer.echo(f"wrote {result.run_dir / 'model.safetensors'} and {result.run_dir / 'model.json'}")


_SENSOR_HELP = (
    "LiDAR preset: tim561 (paper: 15 Hz, 270 deg, 811 beams, 10 m), hokuyo-urg (10 Hz, 180 deg, "
    "512 beams, 5.6 m), hokuyo-utm (7.5 Hz, 270 deg, 768 beams, 11 m), rplidar (10 Hz, 360 deg, "
    "360 beams, 8 m)."
)


@app.command()
def simulate(
    output: Annotated[
        Path,
        typer.Option(
            "--output", "-o", help="Recording to write (.npz); long runs: STEM-000.npz, ..."
        ),
    ],
    scenario: Annotated[
        str,
        typer.Option("--scenario", "-s", help="static (robot stands still) or dynamic (drives)."),
    ] = "dynamic",
    frames: Annotated[int, typer.Option("--frames", "-n", help="Number of scans.", min=1)] = 1000,
    seed: Annotated[int, typer.Option("--seed", help="Same seed, same data.")] = 0,
    sensor: Annotated[str, typer.Option("--sensor", help=_SENSOR_HELP)] = "tim561",
    people: Annotated[
        int, typer.Option("--people", help="People in the building at once.", min=0)
    ] = 8,
    grid: GridOpt = 100,
    res: ResOpt = 0.1,
    odom_drift: Annotated[
        float,
        typer.Option(
            "--odom-drift", help="Odometry error per metre driven (0: poses are exact).", min=0.0
        ),
    ] = 0.0,
    episode_frames: Annotated[
        int,
        typer.Option("--episode-frames", help="Frames per world before a new one is built.", min=2),
    ] = 1500,
    chunk_frames: Annotated[
        int,
        typer.Option(
            "--chunk-frames",
            help="Write runs longer than this as several files of whole episodes (0: one file); "
            "dense ground-truth flow takes 80 kB per frame in memory.",
            min=0,
        ),
    ] = 6000,
    workers: Annotated[
        int, typer.Option("--workers", "-j", help="Processes to simulate with.", min=1)
    ] = 1,
    flow_storage: Annotated[
        str,
        typer.Option(
            "--flow-storage",
            help="dense: flow_backward/flow_forward (N, 2, H, W); sparse: only non-zero cells "
            "(flow_*_cells, flow_*_values; read with lidarflow.sim.dense_flow), far smaller.",
        ),
    ] = "dense",
) -> None:
    """Simulate 2-D LiDAR scans of people walking in offices, with exact ground-truth flow.

    Writes recordings like `convert`, plus the ground truth in extras: flow_backward and
    flow_forward (N, 2, H, W) float16 in cells (channel 0 column, 1 row; index t holds B^t or
    F^t; the last frame of each episode is zero), moving (N, H, W) and true_poses (N, 3); the
    recording's poses are the odometry. Every episode is a new floor plan; the data depend only
    on the seed. The paper's sets: --frames 36000 (training) and --frames 7200 (validation).
    """
    import time

    from lidarflow.scan import GridSpec
    from lidarflow.sim import (
        PRESETS,
        PeopleConfig,
        PlatformConfig,
        SimConfig,
        lidar_preset,
        write_simulation,
    )

    if scenario not in ("static", "dynamic"):
        raise typer.BadParameter(f"static or dynamic, not {scenario!r}", param_hint="--scenario")
    if sensor not in PRESETS:
        choices = ", ".join(PRESETS)
        raise typer.BadParameter(f"one of {choices}, not {sensor!r}", param_hint="--sensor")
    if flow_storage not in ("dense", "sparse"):
        hint = "--flow-storage"
        raise typer.BadParameter(f"dense or sparse, not {flow_storage!r}", param_hint=hint)
    config = SimConfig(
        scenario=scenario,
        flow_storage=flow_storage,
        sensor=lidar_preset(sensor),
        people=PeopleConfig(count=people),
        platform=PlatformConfig(odom_drift=odom_drift),
        grid=GridSpec(grid, grid, res),
        episode_frames=episode_frames,
    )
    start = time.perf_counter()
    with _progress(frames, f"simulating {scenario}") as bar:
        paths = write_simulation(
            output, frames, seed, config, chunk_frames, workers, progress=bar.update
        )
    seconds = time.perf_counter() - start
    # The run's record beside its outputs: what was asked, what came out, how fast.
    record = output.with_name(output.name.removesuffix(".npz") + ".json")
    record.write_text(
        json.dumps(
            {
                "command": "lidarflow " + " ".join(sys.argv[1:]),
                "frames": frames,
                "seed": seed,
                "files": [str(p) for p in paths],
                "seconds": round(seconds, 2),
                "scans_per_s": round(frames / seconds, 1),
                "config": config.to_dict(),
            },
            indent=2,
        )
    )
    shown = str(paths[0]) if len(paths) == 1 else f"{len(paths)} files {paths[0]}..{paths[-1].name}"
    typer.echo(
        f"wrote {shown} (+ {record.name}): {frames} {sensor} scans ({scenario}, seed {seed}) "
        f"with ground-truth flow in {seconds:.1f} s ({frames / seconds:.0f} scans/s)"
    )


def _reflow(text: str) -> str:
    """``text`` with the line breaks inside each paragraph joined: typer's rich help keeps them,
    so a docstring's own wrapping and the terminal's would break lines twice."""
    return "\n\n".join(" ".join(p.split()) for p in inspect.cleandoc(text).split("\n\n"))


for _command in app.registered_commands:
    _command.help = _reflow(_command.help or inspect.getdoc(_command.callback) or "")


def main(argv: list[str] | None = None) -> None:
    """Entry point of the console script."""
    debug = os.environ.get("LIDARFLOW_DEBUG") == "1"
    try:
        app(args=argv, prog_name="lidarflow", standalone_mode=True)
    except LidarflowError as err:
        if debug:
            raise
        typer.echo(f"lidarflow: error: {err}", err=True)
        sys.exit(1)
    except KeyboardInterrupt:
        typer.echo("lidarflow: interrupted", err=True)
        sys.exit(130)
    except Exception as err:  # a bug: still one line, with the way to the traceback
        if debug:
            raise
        typer.echo(
            f"lidarflow: internal error: {type(err).__name__}: {err} "
            "(rerun with LIDARFLOW_DEBUG=1 for the traceback, and please report it)",
            err=True,
        )
        sys.exit(1)


if __name__ == "__main__":
    main()
