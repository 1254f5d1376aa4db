"""``convert``, ``info`` and ``show``: recordings in, files and pictures out."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Any

import typer

from lidarflow.cli.app import (
    ForceOpt,
    GridOpt,
    OdomOpt,
    ResOpt,
    TopicOpt,
    app,
    load_input,
    refuse_existing,
)
from lidarflow.errors import BagError, LidarflowError


@app.command()
def convert(
    input: Annotated[Path, typer.Argument(help="Bag (.bag, .bag.zip), ROS 2 bag folder or .mcap.")],
    output: Annotated[Path, typer.Option("--output", "-o", help="Recording to write (.npz).")],
    topic: TopicOpt = None,
    odom_topic: OdomOpt = None,
    grid: GridOpt = 100,
    res: ResOpt = 0.1,
    force: ForceOpt = False,
) -> None:
    """Convert a LaserScan topic into a lidarflow recording (raw scans, stamps, poses).

    The raw ranges are kept, so the commands that read the recording rasterize it on their own
    --grid/--res; here those are the grid every scan is checked on and which the recording's
    meta records.
    """
    from lidarflow.cli.scorable import refuse_without_returns, warn_unknown_beams
    from lidarflow.data.info import stamps_problem
    from lidarflow.scan import GridSpec

    if output.suffix != ".npz" and output.name:  # as Recording.save names it
        output = output.with_name(output.name + ".npz")
    refuse_existing(output, force=force, inputs=[input])
    recording = load_input(input, topic, odom_topic)
    refuse_without_returns(input, recording, "convert")
    warn_unknown_beams(input, recording)
    spec = GridSpec(grid, grid, res)
    recording.check_maps(spec)  # fail now, not in training, if any scan cannot be rasterized
    recording.meta["grid"] = spec.to_dict()
    path = recording.save(output)
    poses = "with poses" if recording.has_poses else "no poses"
    no_mount = "sensor_mount" in recording.meta and recording.meta["sensor_mount"] is None
    if recording.has_poses and no_mount:
        poses += " (the odometry's own frame: the bag has no TF to the scanner)"
    problem = stamps_problem(recording)
    rate = f"an unknown rate ({problem})" if problem else f"{recording.frame_rate:.2f} Hz"
    typer.echo(
        f"wrote {path}: {len(recording)} scans from {recording.meta['topic']} at {rate}, {poses}"
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
    from lidarflow.data.topics import SCAN_TYPES

    report: dict[str, Any] = {"path": str(input)}
    if not is_recording_file(input):
        topics = list_topics(input)
        report["topics"] = [{"topic": t.topic, "type": t.msgtype, "count": t.count} for t in topics]
        if topic is None and not any(t.msgtype in SCAN_TYPES for t in topics):
            _print_info(report, as_json)  # an odometry-only bag: its topics say what it holds
            kinds = " or ".join(t.rsplit("/", 1)[-1] for t in sorted(SCAN_TYPES))
            raise BagError(f"{input}: no scan topic ({kinds}) in this bag; nothing to predict on")
    try:
        recording = load_input(input, topic, notes=False)  # of several, the one read says why
    except LidarflowError:
        if "topics" in report:  # what the bag holds, to pick another --topic from
            _print_info(report, as_json)
        raise
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
            typer.echo(_beams_text(value))
        elif key == "scans_dropped":
            typer.echo(f"{key}: " + ", ".join(f"{k}={v}" for k, v in value.items()))
        elif key == "gaps":
            shown = ", ".join(
                f"{g['seconds']}s before frame {g['before_frame']}" for g in value[:10]
            )
            more = f" (+{len(value) - 10} more)" if len(value) > 10 else ""
            typer.echo(f"gaps: {len(value)}" + (f": {shown}{more}" if value else ""))
        elif key == "clock_jumps":
            more = f" (+{len(value) - 10} more)" if len(value) > 10 else ""
            shown = ", ".join(_clock_jump_text(j) for j in value[:10])
            typer.echo(f"clock_jumps: {len(value)}: {shown}{more}")
        elif key == "frame_rate_hz" and value is None:  # stamps_unusable says why
            typer.echo(f"{key}: unknown")
        else:
            typer.echo(f"{key}: {value}")


def _beams_text(beams: dict[str, int]) -> str:
    """``info``'s beam counts in words."""
    total = beams["total"]

    def share(n: int) -> str:
        return f"{n} ({n / total:.1%})" if total else str(n)

    causes = {"zero": "zero", "below_range_min": "below range_min", "neg_inf": "-inf", "nan": "NaN"}
    why = ", ".join(f"{beams[k]} {name}" for k, name in causes.items() if beams.get(k))
    text = (
        f"beams: {total}: {share(beams['returns'])} returns, {share(beams['no_return'])} no "
        f"return (+inf, or at or beyond range_max: free along the beam), {share(beams['unknown'])} "
        f"unknown (the maps leave them unseen{': ' + why if why else ''})"
    )
    if beams.get("at_range_max"):
        text += f"; {beams['at_range_max']} at exactly range_max"
    return text


def _clock_jump_text(jump: dict[str, Any]) -> str:
    """One header clock jump of ``info`` (read_bag's ``meta["clock_jumps"]``) in words."""
    poses = ", no poses" if jump.get("poses_matched") is False else ""
    return (
        f"{jump['back_s']}s back before frame {jump['before_frame']}"
        f" (stamps from there +{jump['shift_s']}s{poses})"
    )


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
    force: ForceOpt = False,
) -> None:
    """Draw the occupancy and visibility maps of one frame (sensor at the bottom middle).

    On a simulated recording the ground truth is overlaid: moving cells in red, the forward
    flow as arrows."""
    from lidarflow.errors import RecordingError
    from lidarflow.scan import GridSpec
    from lidarflow.viz.figures import check_picture_path
    from lidarflow.viz.maps import draw_maps

    refuse_existing(output, force=force, inputs=[recording])
    check_picture_path(output)
    rec = load_input(recording, topic)
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
