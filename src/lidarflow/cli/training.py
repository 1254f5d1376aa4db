"""``train``: the recipes, configuration layering and resuming."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Annotated

import typer

from lidarflow.cli.app import TopicOpt, app


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
    arch: Annotated[
        str | None,
        typer.Option(
            "--arch",
            help="Architecture: flownet (LiDAR-FlowNet), deeptracking or sogmp (each with its "
            "own recipe unless --recipe names one).",
        ),
    ] = None,
    ego_motion: Annotated[
        bool,
        typer.Option(
            "--ego-motion",
            help="Compensate the sensor's own motion by the recordings' poses (odometry), so "
            "the net only explains the world's motion.",
        ),
    ] = False,
    recipe: Annotated[
        str | None,
        typer.Option(
            help="Preset: head_only (default: the occupancy head alone), head (a head on a "
            "flow network: --init RUN), paper, blurred, supervised_flow (flow from simulated "
            "truth) or sogmp (the peer's)."
        ),
    ] = None,
    config: Annotated[
        Path | None,
        typer.Option(
            "--config",
            help="JSON or TOML file of settings (partial is fine); a run's config.json works.",
        ),
    ] = None,
    init: Annotated[
        str | None,
        typer.Option(
            "--init",
            help="Start from these weights (run folder, weights file, or "
            "'bundled') instead of from scratch: fine-tuning. A flow-only "
            "model can start one with an occupancy head (the head starts fresh).",
        ),
    ] = None,
    resume: Annotated[
        Path | None,
        typer.Option(
            help="Continue the run in this directory exactly (weights, optimizer, "
            "schedules, RNG, data order); --epochs may extend it."
        ),
    ] = None,
    epochs: Annotated[int | None, typer.Option(help="Epochs (paper: 200).", min=1)] = None,
    batch_size: Annotated[
        int | None, typer.Option(help="Sequences per batch (default 32).", min=1)
    ] = None,
    lr: Annotated[float | None, typer.Option(help="Initial learning rate (default 0.01).")] = None,
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
        typer.Option(
            help="Sampling weight per source, repeated (--mix 3 --mix 1); with two "
            "sources one value is the first's fraction."
        ),
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
        typer.Option(
            help="tail: the last frames of each recording (default); recordings: whole recordings."
        ),
    ] = None,
    topic: TopicOpt = None,
    grid: Annotated[
        int | None, typer.Option("--grid", help="Map size in cells (default 100).")
    ] = None,
    res: Annotated[
        float | None, typer.Option("--res", help="Cell size in metres (default 0.1).")
    ] = None,
    device: Annotated[str | None, typer.Option(help="auto (CUDA if available), cpu, cuda.")] = None,
    amp: Annotated[
        str | None,
        typer.Option(
            help="none (fp32 reference), bf16 autocast, or auto: bf16 where the device computes "
            "it natively, fp32 elsewhere (the head recipe's default)."
        ),
    ] = None,
    compile: Annotated[
        bool,
        typer.Option(
            "--compile",
            help="torch.compile each ConvGRU cell (pays on long runs; "
            "--set runtime.compile=step compiles the whole step).",
        ),
    ] = False,
    channels_last: Annotated[
        bool, typer.Option("--channels-last", help="Channels-last memory format.")
    ] = False,
    threads: Annotated[
        int | None,
        typer.Option(
            help="CPU threads (0: one per core, the default: training steps big batches).", min=0
        ),
    ] = None,
    seed: Annotated[int | None, typer.Option(help="Random seed (default 0).")] = None,
    max_minutes: Annotated[
        float | None,
        typer.Option(
            help="Wall-clock budget: stop after the first epoch that ends past this many "
            "minutes, finished as if --epochs were that epoch (--resume continues).",
            min=0,
        ),
    ] = None,
    set_: Annotated[
        list[str] | None,
        typer.Option(
            "--set",
            help="Any setting as section.field=value, e.g. optim.lr=0.003, "
            "loss.smoothness=0.1, data.stride=5 (repeatable; applied last).",
        ),
    ] = None,
    force: Annotated[
        bool,
        typer.Option("--force", help="Start the run in -o over (its old files are removed)."),
    ] = False,
) -> None:
    """``lidarflow train``: the help text above says it all (kept there for --help)."""
    import dataclasses

    from lidarflow.errors import OutputError, TrainError
    from lidarflow.train.config_io import build_config, config_from_dict, load_config_file
    from lidarflow.train.loop import train as run_training
    from lidarflow.train.recipes import default_recipe

    flags = {
        "model.name": arch,
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
        "runtime.max_minutes": max_minutes,
    }
    if resume is not None:
        if force:
            raise typer.BadParameter(
                "--resume continues a run, --force starts one over; give one", param_hint="--force"
            )
        if output is not None and output.resolve() != resume.resolve():
            raise typer.BadParameter(
                f"--resume {resume} and -o {output} name different runs; give one",
                param_hint="--resume",
            )
        # how the run executes may change (device, amp, threads...), not what it computes
        free = {"optim.epochs"} | {k for k in flags if k.startswith("runtime.")} - {"runtime.seed"}
        # a run copied elsewhere names its recordings again (checked below)
        moved = {"data.val_sources"}
        changed = [k for k, v in flags.items() if v is not None and k not in free | moved]
        changed += ["--ego-motion"] if ego_motion else []
        keys = {o: o.split("=", 1)[0].strip() for o in set_ or ()}
        runtime_sets = [
            o
            for o, k in keys.items()
            if (k.startswith("runtime.") and k != "runtime.seed") or k == "optim.epochs"
        ]
        changed += [f"--set {o}" for o in keys if o not in runtime_sets]
        if changed or recipe or config:
            raise typer.BadParameter(
                "a resumed run keeps its config (only --epochs and runtime options may change); "
                f"drop {', '.join(changed) or '--recipe/--config'} or start a new run",
                param_hint="--resume",
            )
        if not (resume / "config.json").is_file():
            raise TrainError(
                f"{resume}: not a training run (no config.json); --resume takes a folder that "
                "`lidarflow train -o` wrote"
            )
        saved = config_from_dict(load_config_file(resume / "config.json"))
        kept = {k: v for k, v in flags.items() if k in free}
        for key, recorded, given, how in (
            ("data.sources", saved.data.sources, data, "DATA..."),
            ("data.val_sources", saved.data.val_sources, val, "--val V..."),
        ):
            found = _found_again(
                resume, list(recorded), [os.path.abspath(g) for g in given or ()], how
            )
            if found is not None:
                kept[key] = found
        cfg = build_config(saved.recipe, resume / "config.json", kept, runtime_sets)
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
            section = in_file.get("model")  # not a table: build_config says so, in one line
            named = arch or (section.get("name") if isinstance(section, dict) else None)
            recipe = default_recipe(named, ego_motion)
        cfg = build_config(recipe, config, flags, set_ or ())
        if ego_motion:  # added to, not replacing, the rest of the model
            cfg = dataclasses.replace(cfg, model=dataclasses.replace(cfg.model, ego_motion=True))
        _refuse_inputs_in(output, [*cfg.data.sources, *cfg.data.val_sources, cfg.model.init])
        run_dir = output
    from tqdm import tqdm

    try:
        result = run_training(
            cfg.validate(), run_dir, resume=resume is not None, echo=tqdm.write, start_over=force
        )
    except KeyboardInterrupt as interrupt:
        raise KeyboardInterrupt(_where_it_stopped(run_dir)) from interrupt
    except (OSError, OutputError) as err:  # a full disk, mostly: say how to go on once fixed
        named = isinstance(err, OSError) and err.filename and err.strerror
        what = f"{err.filename}: {err.strerror}" if named else str(err)
        raise TrainError(f"{what}; {_where_it_stopped(run_dir)}") from err
    typer.echo(f"wrote {result.run_dir / 'model.safetensors'} and {result.run_dir / 'model.json'}")


def _refuse_inputs_in(run_dir: Path, inputs: list[str | None]) -> None:
    """Refuse a run folder that is, or holds, what the run reads (``--force`` would remove
    it), the sources' glob patterns expanded."""
    import glob

    from lidarflow.atomic import check_not_input

    check_not_input(run_dir, [m for s in inputs if s for m in [s, *glob.glob(s)]])


def _where_it_stopped(run_dir: Path) -> str:
    """What a user who pressed Ctrl-C needs next: whether the run resumes, and how."""
    from lidarflow.errors import TrainError
    from lidarflow.train.checkpoint import latest_epoch

    try:
        done = latest_epoch(run_dir)
    except TrainError:
        done = 0
    if done:
        return f"`lidarflow train --resume {run_dir}` continues {run_dir} after epoch {done}"
    return f"no epoch of {run_dir} finished; run the same command again to start it over"


def _found_again(run: Path, recorded: list[str], given: list[str], how: str) -> list[str] | None:
    """The recordings a resumed run continues on: ``None`` to keep ``recorded``, or ``given``
    where the run was copied elsewhere (every recorded path gone, the same names given).
    Raises :class:`TrainError` for other recordings, or for recorded ones gone and not given."""
    from lidarflow.errors import TrainError

    missing = [r for r in recorded if not os.path.exists(r)]
    if given and given != recorded:
        names = [os.path.basename(r) for r in recorded]
        if missing != recorded or [os.path.basename(g) for g in given] != names:
            raise TrainError(f"{run} was trained on {recorded}, not {given}")
        return given
    if missing:
        raise TrainError(
            f"{run} was trained on {', '.join(missing)}, not there any more; give the "
            f"recordings again where they are now: lidarflow train {how} --resume {run}"
        )
    return None
