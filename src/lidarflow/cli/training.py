"""``train``: its options and messages; the config a command line resolves to is
:mod:`lidarflow.train.invocation`'s."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

import typer

from lidarflow.cli.app import TopicOpt, app
from lidarflow.cli.options import command_options


@dataclass(frozen=True)
class TrainOptions:
    """``train``'s command line."""

    data: Annotated[
        list[str] | None,
        typer.Argument(
            help="Training data sources: recordings (.npz), bags / ROS 2 bag folders / .mcap "
            "(converted on the fly), folders of .npz, or quoted glob patterns. Each argument is "
            "one source for --mix.",
            show_default=False,
        ),
    ] = None
    output: Annotated[
        Path | None, typer.Option("--output", "-o", help="Run directory to create.")
    ] = None
    arch: Annotated[
        str | None,
        typer.Option(
            "--arch",
            help="Architecture: flownet (LiDAR-FlowNet), deeptracking or sogmp (each with its "
            "own recipe unless --recipe names one).",
        ),
    ] = None
    ego_motion: Annotated[
        bool,
        typer.Option(
            "--ego-motion",
            help="Compensate the sensor's own motion by the recordings' poses (odometry), so "
            "the net only explains the world's motion.",
        ),
    ] = False
    recipe: Annotated[
        str | None,
        typer.Option(
            help="Preset: head_only (default: the occupancy head alone), head (a head on a "
            "flow network: --init RUN), paper, blurred, supervised_flow (flow from simulated "
            "truth) or sogmp (the peer's)."
        ),
    ] = None
    config: Annotated[
        Path | None,
        typer.Option(
            "--config",
            help="JSON or TOML file of settings (partial is fine); a run's config.json works.",
        ),
    ] = None
    init: Annotated[
        str | None,
        typer.Option(
            "--init",
            help="Start from these weights (run folder, weights file, or "
            "'bundled') instead of from scratch: fine-tuning. A flow-only "
            "model can start one with an occupancy head (the head starts fresh).",
        ),
    ] = None
    resume: Annotated[
        Path | None,
        typer.Option(
            help="Continue the run in this directory exactly (weights, optimizer, "
            "schedules, RNG, data order); --epochs may extend it."
        ),
    ] = None
    epochs: Annotated[int | None, typer.Option(help="Epochs (paper: 200).", min=1)] = None
    batch_size: Annotated[
        int | None, typer.Option(help="Sequences per batch (default 32).", min=1)
    ] = None
    lr: Annotated[float | None, typer.Option(help="Initial learning rate (default 0.01).")] = None
    optimizer: Annotated[str | None, typer.Option(help="adam (default), adamw or sgd.")] = None
    grad_clip: Annotated[
        float | None, typer.Option(help="Clip the global gradient norm to this (0: off, default).")
    ] = None
    seq_len: Annotated[
        int | None, typer.Option(help="Frames per sequence (default 20).", min=2)
    ] = None
    warmup: Annotated[
        int | None, typer.Option(help="Frames that only warm up the state (default 10).", min=0)
    ] = None
    no_gaussian: Annotated[
        bool, typer.Option("--no-gaussian", help="Ablation: no Gaussian filter in the loss.")
    ] = False
    mix: Annotated[
        list[float] | None,
        typer.Option(
            help="Sampling weight per source, repeated (--mix 3 --mix 1); with two "
            "sources one value is the first's fraction."
        ),
    ] = None
    val: Annotated[
        list[str] | None,
        typer.Option("--val", help="Validation recordings (repeatable); then nothing is held out."),
    ] = None
    val_fraction: Annotated[
        float | None, typer.Option(help="Share held out for validation (default 0.1).")
    ] = None
    val_split: Annotated[
        str | None,
        typer.Option(
            help="tail: the last frames of each recording (default); recordings: whole recordings."
        ),
    ] = None
    topic: TopicOpt = None
    grid: Annotated[
        int | None, typer.Option("--grid", help="Map size in cells (default 100).")
    ] = None
    res: Annotated[
        float | None, typer.Option("--res", help="Cell size in metres (default 0.1).")
    ] = None
    device: Annotated[str | None, typer.Option(help="auto (CUDA if available), cpu, cuda.")] = None
    amp: Annotated[
        str | None,
        typer.Option(
            help="none (fp32 reference), bf16 autocast, or auto: bf16 where the device computes "
            "it natively, fp32 elsewhere (the head recipe's default)."
        ),
    ] = None
    compile: Annotated[
        bool,
        typer.Option(
            "--compile",
            help="torch.compile each ConvGRU cell (pays on long runs; "
            "--set runtime.compile=step compiles the whole step).",
        ),
    ] = False
    channels_last: Annotated[
        bool, typer.Option("--channels-last", help="Channels-last memory format.")
    ] = False
    threads: Annotated[
        int | None,
        typer.Option(
            help="CPU threads (0: one per core, the default: training steps big batches).", min=0
        ),
    ] = None
    seed: Annotated[int | None, typer.Option(help="Random seed (default 0).")] = None
    max_minutes: Annotated[
        float | None,
        typer.Option(
            help="Wall-clock budget: stop after the first epoch that ends past this many "
            "minutes, finished as if --epochs were that epoch (--resume continues).",
            min=0,
        ),
    ] = None
    set_: Annotated[
        list[str] | None,
        typer.Option(
            "--set",
            help="Any setting as section.field=value, e.g. optim.lr=0.003, "
            "loss.smoothness=0.1, data.stride=5 (repeatable; applied last).",
        ),
    ] = None
    force: Annotated[
        bool,
        typer.Option("--force", help="Start the run in -o over (its old files are removed)."),
    ] = False

    def flags(self) -> dict[str, Any]:
        """The settings these flags give (``section.field``), ``None`` where not given."""
        init = self.init if self.init in (None, "bundled") else os.path.abspath(self.init)
        return {
            "model.name": self.arch,
            "model.init": init,
            "optim.epochs": self.epochs,
            "optim.batch_size": self.batch_size,
            "optim.lr": self.lr,
            "optim.name": self.optimizer,
            "optim.grad_clip": self.grad_clip,
            "data.seq_len": self.seq_len,
            "data.warmup": self.warmup,
            "schedule.gaussian": False if self.no_gaussian else None,
            "data.mix": self.mix or None,
            "data.val_sources": [os.path.abspath(v) for v in self.val] if self.val else None,
            "data.val_fraction": self.val_fraction,
            "data.val_split": self.val_split,
            "data.topic": self.topic,
            "data.grid": self.grid,
            "data.res": self.res,
            "runtime.device": self.device,
            "runtime.amp": self.amp,
            "runtime.compile": "cells" if self.compile else None,
            "runtime.channels_last": True if self.channels_last else None,
            "runtime.threads": self.threads,
            "runtime.seed": self.seed,
            "runtime.max_minutes": self.max_minutes,
        }


@app.command(
    help="Train LiDAR-FlowNet or a peer (DeepTracking, SOGMP), self-supervised, on recordings "
    "and bags.\n\n"
    "By default (--recipe head_only) the bundled occupancy head, which has no flow network, is "
    "fitted to your recordings, a few CPU-minutes. Settings come from the recipe, then "
    "--config, then these flags, then --set. The run directory gets its config, metrics, a "
    "checkpoint every epoch and model.safetensors + model.json for the other commands; "
    "torchrun runs it on several processes.",
    epilog="Examples:\n\n"
    "lidarflow train real.npz 'sim/*.npz' --mix 0.5 -o runs/a  (half of each epoch from each)\n\n"
    "lidarflow train a.bag --recipe blurred --set loss.smoothness=0.1 -o runs/b\n\n"
    "lidarflow train my_robot.bag -o runs/h  (the bundled head, fitted to your robot)\n\n"
    "lidarflow train 'sim/*.npz' my_robot.bag --recipe blurred -o runs/flow; lidarflow train "
    "my_robot.bag --recipe head --init runs/flow -o runs/h  (a head on your flow network)\n\n"
    "lidarflow train drive.npz --ego-motion -o runs/e  (odometry-compensated; needs poses)\n\n"
    "lidarflow train drive.npz --arch deeptracking -o runs/d  (the DeepTracking baseline)\n\n"
    "lidarflow train drive.npz --arch sogmp --batch-size 8 --epochs 5 -o runs/s  (the SOGMP "
    "peer, its own recipe)\n\n"
    "lidarflow train --resume runs/a --epochs 300  (continue exactly, then extend)\n\n"
    "torchrun --nproc_per_node 2 -m lidarflow.cli train DATA... -o runs/c",
)
@command_options(TrainOptions)
def train(options: TrainOptions) -> None:
    """``lidarflow train``: the help text above says it all (kept there for --help)."""
    from lidarflow.train.invocation import TrainRequest

    o = options
    request = TrainRequest(
        o.data or [], o.flags(), o.recipe, o.config, o.set_ or [], o.ego_motion, o.val or []
    )
    if o.resume is not None:
        cfg, run_dir = _resumed(o, o.resume, request), o.resume
    else:
        cfg, run_dir = _new_run(o, request)
    _run(cfg, run_dir, o.resume is not None, o.force)


def _resumed(options: TrainOptions, resume: Path, request: Any) -> Any:
    """The config of the run ``--resume`` continues; a usage error where the command line
    contradicts it."""
    from lidarflow.train.invocation import ResumeConflictError, resumed_run_config

    if options.force:
        raise typer.BadParameter(
            "--resume continues a run, --force starts one over; give one", param_hint="--force"
        )
    output = options.output
    if output is not None and output.resolve() != resume.resolve():
        raise typer.BadParameter(
            f"--resume {resume} and -o {output} name different runs; give one",
            param_hint="--resume",
        )
    try:
        return resumed_run_config(resume, request)
    except ResumeConflictError as err:  # a usage error: the command line asked for it
        raise typer.BadParameter(str(err), param_hint="--resume") from err


def _new_run(options: TrainOptions, request: Any) -> tuple[Any, Path]:
    """The config of a new run and its folder (``-o``), checked before any work."""
    from lidarflow.train.invocation import new_run_config, refuse_inputs_in

    if options.output is None:
        raise typer.BadParameter(
            "name the run directory with -o RUN_DIR (or --resume RUN_DIR)", param_hint="-o"
        )
    if not options.data and options.config is None:
        raise typer.BadParameter("give training data: recordings or bags", param_hint="DATA")
    cfg = new_run_config(request)
    refuse_inputs_in(options.output, cfg)
    return cfg, options.output


def _run(cfg: Any, run_dir: Path, resume: bool, start_over: bool) -> None:
    """Train ``cfg`` into ``run_dir``; where it stops (Ctrl-C, a full disk), say how to go on."""
    from tqdm import tqdm

    from lidarflow.errors import OutputError, TrainError
    from lidarflow.train.invocation import where_it_stopped
    from lidarflow.train.loop import train as run_training

    try:
        result = run_training(
            cfg.validate(), run_dir, resume=resume, echo=tqdm.write, start_over=start_over
        )
    except KeyboardInterrupt as interrupt:
        raise KeyboardInterrupt(where_it_stopped(run_dir)) from interrupt
    except (OSError, OutputError) as err:  # a full disk, mostly: say how to go on once fixed
        named = isinstance(err, OSError) and err.filename and err.strerror
        what = f"{err.filename}: {err.strerror}" if named else str(err)
        raise TrainError(f"{what}; {where_it_stopped(run_dir)}") from err
    typer.echo(f"wrote {result.run_dir / 'model.safetensors'} and {result.run_dir / 'model.json'}")
