"""``simulate``: recordings with ground-truth flow from the simulator."""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

import typer

from lidarflow.atomic import discard, write_text
from lidarflow.cli.app import ForceOpt, GridOpt, ResOpt, app, progress_bar, refuse_existing
from lidarflow.cli.options import command_options

_SENSOR_HELP = (
    "LiDAR preset: tim561 (the paper's: 15 Hz, 270 deg, 811 beams, 10 m), hokuyo-urg, "
    "hokuyo-utm or rplidar."
)


@dataclass(frozen=True)
class SimulateOptions:
    """``simulate``'s command line."""

    output: Annotated[
        Path,
        typer.Option(
            "--output", "-o", help="Recording to write (.npz); long runs: STEM-000.npz, ..."
        ),
    ]
    scenario: Annotated[
        str,
        typer.Option("--scenario", "-s", help="static (robot stands still) or dynamic (drives)."),
    ] = "dynamic"
    frames: Annotated[int, typer.Option("--frames", "-n", help="Number of scans.", min=1)] = 1000
    seed: Annotated[int, typer.Option("--seed", help="Same seed, same data.")] = 0
    sensor: Annotated[str, typer.Option("--sensor", help=_SENSOR_HELP)] = "tim561"
    people: Annotated[
        int, typer.Option("--people", help="People in the building at once.", min=0)
    ] = 8
    walkers: Annotated[
        str,
        typer.Option(
            "--walkers", help="social (social forces, groups) or legacy (the first model)."
        ),
    ] = "legacy"
    grid: GridOpt = 100
    res: ResOpt = 0.1
    odom_drift: Annotated[
        float,
        typer.Option(
            "--odom-drift", help="Odometry error per metre driven (0: poses are exact).", min=0.0
        ),
    ] = 0.0
    episode_frames: Annotated[
        int,
        typer.Option("--episode-frames", help="Frames per world before a new one is built.", min=2),
    ] = 1500
    chunk_frames: Annotated[
        int,
        typer.Option(
            "--chunk-frames",
            help="Write runs longer than this as several files of whole episodes (0: one file); "
            "dense ground-truth flow takes 80 kB per frame in memory.",
            min=0,
        ),
    ] = 6000
    workers: Annotated[
        int, typer.Option("--workers", "-j", help="Processes to simulate with.", min=1)
    ] = 1
    flow_storage: Annotated[
        str,
        typer.Option(
            "--flow-storage",
            help="dense: flow_backward/flow_forward (N, 2, H, W); sparse: only non-zero cells "
            "(flow_*_cells, flow_*_values; read with lidarflow.sim.dense_flow), far smaller.",
        ),
    ] = "dense"
    force: ForceOpt = False


@app.command()
@command_options(SimulateOptions)
def simulate(options: SimulateOptions) -> None:
    """Simulate 2-D LiDAR scans of people walking in offices, with exact ground-truth flow.

    Writes recordings like `convert` with the ground truth in extras (flow_backward,
    flow_forward, moving, true_poses; see lidarflow.sim), and the run's record (.json) beside.
    The data depend only on the seed; the paper's sets: --frames 36000 and --frames 7200.
    """
    import time

    from lidarflow.sim import write_simulation

    o = options
    config = _sim_config(o)
    output = o.output
    if output.suffix != ".npz" and output.name:  # as Recording.save names it
        output = output.with_name(output.name + ".npz")
    stem = output.name.removesuffix(".npz")
    record = output.with_name(stem + ".json")
    chunks = sorted(output.parent.glob(f"{stem}-[0-9][0-9][0-9].npz"))
    refuse_existing(output, record, *chunks, force=o.force)
    start = time.perf_counter()
    with progress_bar(o.frames, f"simulating {o.scenario}") as bar:
        paths = write_simulation(
            output, o.frames, o.seed, config, o.chunk_frames, o.workers, progress=bar.update
        )
    seconds = time.perf_counter() - start
    for old in {output, *chunks} - set(paths):  # --force: the last run's files not rewritten
        discard(old)
    _write_record(record, o, paths, seconds, config)
    n = o.frames
    shown = str(paths[0]) if len(paths) == 1 else f"{len(paths)} files {paths[0]}..{paths[-1].name}"
    typer.echo(
        f"wrote {shown} (+ {record.name}): {n} {o.sensor} scans ({o.scenario}, seed {o.seed}) "
        f"with ground-truth flow in {seconds:.1f} s ({n / seconds:.0f} scans/s)"
    )


def _sim_config(options: SimulateOptions) -> Any:
    """The simulator's config; a usage error for a name it does not know."""
    from lidarflow.scan import GridSpec
    from lidarflow.sim import PRESETS, PeopleConfig, PlatformConfig, SimConfig, lidar_preset

    o = options
    if o.scenario not in ("static", "dynamic"):
        raise typer.BadParameter(f"static or dynamic, not {o.scenario!r}", param_hint="--scenario")
    if o.sensor not in PRESETS:
        choices = ", ".join(PRESETS)
        raise typer.BadParameter(f"one of {choices}, not {o.sensor!r}", param_hint="--sensor")
    if o.walkers not in ("social", "legacy"):
        raise typer.BadParameter(f"social or legacy, not {o.walkers!r}", param_hint="--walkers")
    if o.flow_storage not in ("dense", "sparse"):
        hint = "--flow-storage"
        raise typer.BadParameter(f"dense or sparse, not {o.flow_storage!r}", param_hint=hint)
    return SimConfig(
        scenario=o.scenario,
        flow_storage=o.flow_storage,
        sensor=lidar_preset(o.sensor),
        people=PeopleConfig(count=o.people),
        walkers=o.walkers,
        platform=PlatformConfig(odom_drift=o.odom_drift),
        grid=GridSpec(o.grid, o.grid, o.res),
        episode_frames=o.episode_frames,
    )


def _write_record(
    record: Path, options: SimulateOptions, paths: list[Path], seconds: float, config: Any
) -> None:
    """The run's record beside its outputs: what was asked, what came out, how fast."""
    done = {
        "command": "lidarflow " + " ".join(sys.argv[1:]),
        "frames": options.frames,
        "seed": options.seed,
        "files": [str(p) for p in paths],
        "seconds": round(seconds, 2),
        "scans_per_s": round(options.frames / seconds, 1),
        "config": config.to_dict(),
    }
    write_text(record, json.dumps(done, indent=2))
