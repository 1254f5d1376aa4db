"""The ``lidarflow`` application, the options its commands share, and reading inputs."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from lidarflow.errors import LidarflowError

if TYPE_CHECKING:
    from lidarflow.scan import GridSpec

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


def _print_version(value: bool) -> None:
    if value:
        from importlib.metadata import PackageNotFoundError, version

        try:
            number = version("lidarflow")
        except PackageNotFoundError:  # a source tree on PYTHONPATH, not installed
            number = "unknown (not installed)"
        typer.echo(f"lidarflow {number}")
        raise typer.Exit()


@app.callback()
def _options(
    version: Annotated[
        bool,
        typer.Option(
            "--version", callback=_print_version, is_eager=True, help="Print the version and exit."
        ),
    ] = False,
) -> None:
    pass


TopicOpt = Annotated[
    str | None,
    typer.Option(
        "--topic",
        "-t",
        help="Scan topic (LaserScan, or MultiEchoLaserScan: nearest echo); default: the bag's, "
        "of several `scan`, else the busiest.",
    ),
]
OdomOpt = Annotated[
    str | None,
    typer.Option(
        "--odom-topic",
        help="Odometry (Odometry or PoseStamped) topic for the sensor's poses; default: the "
        "bag's (`info` says which), moved to the scanner by the bag's TF.",
    ),
]
GridOpt = Annotated[int, typer.Option("--grid", help="Map size in cells (square grid).", min=4)]
ResOpt = Annotated[float, typer.Option("--res", help="Cell size in metres.", min=1e-4)]
#: For commands that run one model: its own grid unless given.
ModelGridOpt = Annotated[
    int | None,
    typer.Option(
        "--grid",
        help="Map size in cells (square grid; default: the model's own, 100 for the bundled).",
        min=4,
    ),
]
ModelResOpt = Annotated[
    float | None,
    typer.Option(
        "--res",
        help="Cell size in metres (default: the model's own, 0.1 for the bundled).",
        min=1e-4,
    ),
]
MovingOpt = Annotated[
    float | None,
    typer.Option(
        "--moving-threshold",
        help="Moving-object segmentation: an occupied cell moves when its flow, less the "
        "platform's, exceeds this many cells per frame (default 0.4).",
        min=0.0,
    ),
]
CombineOpt = Annotated[
    bool,
    typer.Option(
        "--combine",
        help="The online combination (the model and the simple predictors weighed by the scans "
        "that arrive) decides every frame ahead; by default the frames 2..--horizon.",
    ),
]
NoCombineOpt = Annotated[
    bool,
    typer.Option(
        "--no-combine", help="The model alone at every frame ahead, without the combination."
    ),
]


def combine_choice(combine: bool, no_combine: bool) -> bool | None:
    """``Predictor``'s ``combine`` from the two flags: ``None`` (its default) for neither."""
    if combine and no_combine:
        raise typer.BadParameter("give --combine or --no-combine, not both")
    return True if combine else (False if no_combine else None)


LearnOpt = Annotated[
    bool,
    typer.Option(
        "--learn",
        help="The model's head keeps learning on the stream, each scan the label of the "
        "prediction made for it (a head-only model such as the bundled one, with PyTorch).",
    ),
]


ForceOpt = Annotated[
    bool, typer.Option("--force", help="Overwrite the output if it exists (else refused).")
]
#: One thread by default: a streaming model steps one small map at a time, which a second
#: thread barely speeds up on an idle machine and slows many times over on a busy one
#: (benchmarks/bench_threads.py, benchmarks/results/threads.json).
DEFAULT_THREADS = 1
ThreadsOpt = Annotated[
    int,
    typer.Option(
        "--threads",
        help="CPU threads for the model (0: one per core, PyTorch's own default; more than 1 "
        "pays only on an idle machine).",
        min=0,
    ),
]


def error_text(err: BaseException, what: str = "this") -> str | None:
    """``err`` in one line where it is the user's to fix: a lidarflow error, the file system's
    refusal, or a package of an extra that ``what`` needs missing; ``None`` for a bug."""
    from lidarflow.extras import missing_extra

    if isinstance(err, LidarflowError):
        return str(err)
    if isinstance(err, OSError):
        return (f"{err.filename}: " if err.filename else "") + (err.strerror or str(err))
    missing = missing_extra(err, what) if isinstance(err, ImportError) else None
    return None if missing is None else str(missing)


def use_threads(threads: int) -> None:
    """Run PyTorch on ``threads`` CPU threads (0: its default), where PyTorch is installed."""
    from lidarflow.extras import torch_available

    if threads > 0 and torch_available():
        import torch

        torch.set_num_threads(threads)


def refuse_existing(
    *paths: Path | None,
    force: bool = False,
    folder: bool = False,
    inputs: Sequence[Path | str | None] = (),
) -> None:
    """Refuse, before any work, each output (a ``folder`` or a file) that may not be written:
    :func:`lidarflow.atomic.check_not_input` against ``inputs``, then ``check_writable``."""
    from lidarflow.atomic import check_not_input, check_writable

    for path in paths:
        if path is not None:
            check_not_input(path, inputs)
            check_writable(path, force, folder)


def progress_bar(total: int | None, desc: str) -> Any:
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit="scan", disable=None, leave=False)


def eval_progress(name: str, total: int) -> Any:
    return progress_bar(total, f"evaluating {Path(name).name}")


def load_input(
    path: Path, topic: str | None = None, odom_topic: str | None = None, notes: bool = True
) -> Any:
    """Read a recording or bag for a command, saying on stderr how much of a cut-short bag was
    read and, with ``notes``, which of several scan or odometry topics was read."""
    from lidarflow.data import load_any
    from lidarflow.data.sources import recovered_notes, topic_notes

    with progress_bar(None, f"reading {path.name}") as bar:
        recording = load_any(path, topic=topic, odom_topic=odom_topic, progress=bar.update)
    for note in (topic_notes if notes else recovered_notes)(path, recording):
        typer.echo(note, err=True)
    return recording


#: What every --model that loads PyTorch weights takes; each command's help says whether it
#: also takes an .onnx file (which runs, but does not train or export).
TORCH_MODEL_SOURCES = "a run folder, .safetensors or model.json from `lidarflow train`"
ModelOpt = Annotated[
    Path | None,
    typer.Option(
        "--model",
        "-m",
        help=f"Model: {TORCH_MODEL_SOURCES}, an .onnx file from `lidarflow export`, or "
        "`bundled` (the default).",
    ),
]
ExportModelOpt = Annotated[
    Path | None,
    typer.Option(
        "--model",
        "-m",
        help=f"Model to export: {TORCH_MODEL_SOURCES} or `bundled` (the default); not an .onnx "
        "file.",
    ),
]


def bundled_model_available() -> bool:
    """Whether this installation has the bundled model it can run: its weights, or without
    PyTorch its ONNX export."""
    from lidarflow.extras import torch_available
    from lidarflow.models.presets import bundled_model_dir

    name = "model.safetensors" if torch_available() else "model.onnx"
    return (bundled_model_dir() / name).exists()


def completed_grid(recorded: GridSpec | None, grid: int | None, res: float | None) -> GridSpec:
    """The grid ``--grid/--res`` ask for, completed from ``recorded`` (a model's own), else
    the bundled model's."""
    from lidarflow.scan import GridSpec

    base = recorded or GridSpec()
    return GridSpec(grid or base.height, grid or base.width, res or base.res)


def model_grid(model: Path | None, grid: int | None, res: float | None) -> GridSpec | None:
    """The grid a command runs ``model`` on: ``None`` (the model's own) unless ``--grid`` or
    ``--res`` is given, else :func:`completed_grid` from the model's own."""
    if grid is None and res is None:
        return None
    from lidarflow.predict.backends import load_backend, recorded_grid

    return completed_grid(recorded_grid(load_backend(model)[1]), grid, res)
