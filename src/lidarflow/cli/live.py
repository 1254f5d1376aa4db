"""``live``: a recording played at its pace, predicted scan by scan and served to Foxglove."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from lidarflow.cli.app import (
    DEFAULT_THREADS,
    CombineOpt,
    LearnOpt,
    ModelOpt,
    NoCombineOpt,
    ThreadsOpt,
    TopicOpt,
    app,
    combine_choice,
    load_input,
    progress_bar,
)

if TYPE_CHECKING:
    from lidarflow.live.replay import Served

#: ``lidarflow.live.foxglove.DEFAULT_PORT``, here without importing the SDK for ``--help``.
DEFAULT_PORT = 8765


@app.command()
def live(
    source: Annotated[
        Path, typer.Argument(help="Recording (.npz) or bag/MCAP to play as if it came live.")
    ],
    topic: TopicOpt = None,
    model: ModelOpt = None,
    horizon: Annotated[
        int, typer.Option(help="Frames ahead to predict (predictions fed back).", min=1)
    ] = 1,
    speed: Annotated[
        float,
        typer.Option(help="Times the recorded pace (0: as fast as the model goes).", min=0.0),
    ] = 1.0,
    loop: Annotated[
        bool, typer.Option("--loop", help="Play the recording over and over until stopped.")
    ] = False,
    host: Annotated[
        str, typer.Option(help="Address to serve on (0.0.0.0: every network the machine is on).")
    ] = "127.0.0.1",
    port: Annotated[
        int, typer.Option(help="Port to serve on (0: any free one).", min=0, max=65535)
    ] = DEFAULT_PORT,
    threads: ThreadsOpt = DEFAULT_THREADS,
    combine: CombineOpt = False,
    no_combine: NoCombineOpt = False,
    learn: LearnOpt = False,
) -> None:
    """Play SOURCE scan by scan at its recorded pace, predict each with the model and serve
    the scans, predicted grids, moving cells and the flow (a colour-wheel image) over
    Foxglove's WebSocket protocol: open the printed ws:// address in Foxglove. Ctrl-C stops."""
    from lidarflow.evaluate.horizon import check_horizon
    from lidarflow.live.foxglove import LiveServer
    from lidarflow.live.replay import Served, replay
    from lidarflow.predict import Predictor

    combined = combine_choice(combine, no_combine)
    recording = load_input(source, topic)
    check_horizon(len(recording), horizon, 0, str(source))
    predictor = Predictor(
        model, horizon=horizon, threads=threads or None, combine=combined, learn=learn
    )
    scan_topic = "/" + (recording.meta.get("topic") or "scan").lstrip("/")
    frame_id = recording.meta.get("frame_id") or "laser"
    flow = predictor.backend.capabilities.flow
    served = Served()
    with LiveServer(
        predictor.grid, frame_id, host=host, port=port, horizon=horizon, flow=flow,
        scan_topic=scan_topic,
    ) as server:  # fmt: skip
        pace = "as fast as it goes" if speed == 0 else f"at {speed:g}x its pace"
        typer.echo(
            f"serving {source.name} ({len(recording)} scans, {recording.frame_rate:.1f} Hz) "
            f"{pace}{', looped' if loop else ''} on {server.url}"
        )
        typer.echo(
            "open it in Foxglove: Open connection > Foxglove WebSocket > "
            f"{server.url}; Ctrl-C stops"
        )
        typer.echo("topics: " + " ".join(server.topics))
        stopped = ""
        try:
            with progress_bar(None if loop else len(recording), "serving") as bar:
                replay(recording, predictor, server, speed, loop, bar.update, served)
        except KeyboardInterrupt:  # the way a live server is meant to end: not an error
            stopped = "stopped; "
    typer.echo(stopped + _summary(served))


def _summary(served: Served) -> str:
    """One line: what went out, what a scan cost to predict and to publish, the lag."""
    import numpy as np

    scans, passes = served.scans, served.passes
    line = f"served {scans} scans ({passes} whole pass{'es' if passes != 1 else ''})"
    if scans:
        update = 1e3 * float(np.median(served.update_s))
        publish = 1e3 * float(np.median(served.publish_s))
        line += f"; per scan (median) predict {update:.1f} ms, publish {publish:.1f} ms"
        if served.worst_lag_s > 0.05:
            line += f"; at worst {served.worst_lag_s:.2f} s behind the recording's pace"
    return line
