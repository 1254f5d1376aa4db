"""``ros1``: the predictor live on a robot, as a ROS 1 node."""

from __future__ import annotations

import contextlib
import logging
from typing import Annotated

import typer

from lidarflow.cli.app import (
    DEFAULT_THREADS,
    ModelGridOpt,
    ModelOpt,
    ModelResOpt,
    MovingOpt,
    ThreadsOpt,
    app,
    model_grid,
)


@app.command()
def ros1(
    model: ModelOpt = None,
    topic: Annotated[
        str, typer.Option("--topic", "-t", help="LaserScan topic to predict on.")
    ] = "/scan",
    odom_topic: Annotated[
        str | None,
        typer.Option(
            "--odom-topic",
            help="nav_msgs/Odometry topic for the sensor's poses (moved to the scanner by "
            "/tf); default: none (the bundled model then matches the motion from the scans).",
        ),
    ] = None,
    horizon: Annotated[
        int, typer.Option(help="Frames ahead to predict: also publishes the _kK grids.", min=1)
    ] = 1,
    moving: Annotated[
        bool, typer.Option("--moving", help="Also publish the moving cells (/lidarflow/moving).")
    ] = False,
    grid: ModelGridOpt = None,
    res: ModelResOpt = None,
    moving_threshold: MovingOpt = None,
    queue: Annotated[
        int,
        typer.Option(help="Scans kept while the model is busy; beyond them the oldest are dropped.",
                     min=1),
    ] = 10,
    summary_every: Annotated[
        int, typer.Option(help="Scans between the latency summaries it logs.", min=1)
    ] = 100,
    foxglove: Annotated[
        int | None,
        typer.Option(
            "--foxglove",
            metavar="PORT",
            help="Also serve scans and predictions to Foxglove on this port (ws://HOST:PORT, "
            "as `lidarflow live`; 0: any free port).",
            min=0,
            max=65535,
        ),
    ] = None,
    host: Annotated[
        str, typer.Option(help="Address the Foxglove server listens on (with --foxglove).")
    ] = "127.0.0.1",
    verbose: Annotated[
        bool, typer.Option("--verbose", "-v", help="Also log every scan's latency.")
    ] = False,
    threads: ThreadsOpt = DEFAULT_THREADS,
) -> None:
    """Run a ROS 1 node: per scan on --topic, publish the predicted next map (OccupancyGrid in
    the scan's frame) on /lidarflow/predicted and /lidarflow/decided, stamped with the time it
    predicts. Needs a roscore (ROS_MASTER_URI); stop it with Ctrl-C."""
    from lidarflow.live.ros1 import Ros1Node, check_master, import_ros
    from lidarflow.live.step import LiveStep
    from lidarflow.predict import Predictor
    from lidarflow.predict.moving import MOVING_THRESHOLD

    _log_to_stderr(logging.DEBUG if verbose else logging.INFO)
    check_master(import_ros())  # before loading a model: say at once what is missing
    given = model_grid(model, grid, res)
    predictor = Predictor(
        model,
        given,
        horizon=horizon,
        threads=threads or None,
        moving_threshold=MOVING_THRESHOLD if moving_threshold is None else moving_threshold,
    )
    step = LiveStep(predictor, summary_every=summary_every)
    with contextlib.ExitStack() as stack:
        if foxglove is not None:
            from lidarflow.live.foxglove import LiveServer

            server = stack.enter_context(LiveServer(
                predictor.grid, host=host, port=foxglove, horizon=horizon,
                flow=predictor.backend.capabilities.flow, scan_topic=topic,
            ))  # fmt: skip
            step.sinks.append(server.publish_frame)
            typer.echo(f"lidarflow ros1: serving Foxglove on {server.url}", err=True)
        node = Ros1Node(step, topic, odom_topic, moving, queue=queue)
        node.start()
        try:
            node.spin()
        finally:
            typer.echo(f"lidarflow ros1: latency over {step.latency.describe()}", err=True)


def _log_to_stderr(level: int) -> None:
    """The node's log on stderr, one line a message (rospy configures logging its own way when
    the node starts; this logger does not pass through it)."""
    logger = logging.getLogger("lidarflow.live")
    handler = logging.StreamHandler()
    handler.setFormatter(logging.Formatter("lidarflow ros1: %(message)s"))
    logger.handlers = [handler]
    logger.setLevel(level)
    logger.propagate = False
