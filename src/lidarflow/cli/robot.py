"""``ros1`` and ``ros2``: the predictor live on a robot, as a ROS 1 or a ROS 2 node."""

from __future__ import annotations

import contextlib
import functools
import logging
import os
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Annotated, Any

import typer

from lidarflow.cli.app import (
    DEFAULT_THREADS,
    CombineOpt,
    LearnOpt,
    ModelGridOpt,
    ModelOpt,
    ModelResOpt,
    MovingOpt,
    NoCombineOpt,
    ThreadsOpt,
    app,
    combine_choice,
    model_grid,
)
from lidarflow.cli.options import command_options

if TYPE_CHECKING:
    from lidarflow.live.rosnode import RosNode
    from lidarflow.live.step import LiveStep


#: The options only ``ros2`` has: ``ros1`` leaves them at their defaults.
ROS2_ONLY = ("scan_qos", "grid_qos")


@dataclass(frozen=True)
class NodeOptions:
    """The command line of ``ros1`` and ``ros2`` (:func:`lidarflow.cli.options.command_options`):
    one node, either transport; the QoS fields are ``ros2``'s alone (:data:`ROS2_ONLY`)."""

    model: ModelOpt = None
    topic: Annotated[
        str, typer.Option("--topic", "-t", help="LaserScan topic to predict on.")
    ] = "/scan"
    odom_topic: Annotated[
        str | None,
        typer.Option(
            "--odom-topic",
            help="nav_msgs/Odometry topic for the sensor's poses (moved to the scanner by /tf); "
            "default: none (the bundled model then matches the motion from the scans).",
        ),
    ] = None
    horizon: Annotated[
        int, typer.Option(help="Frames ahead to predict: also publishes the _kK grids.", min=1)
    ] = 1
    moving: Annotated[
        bool, typer.Option("--moving", help="Also publish the moving cells (/lidarflow/moving).")
    ] = False
    planner_grid: Annotated[
        bool,
        typer.Option(
            "--planner-grid",
            help="Also publish /lidarflow/planner_grid: per cell the largest predicted probability "
            "over the --horizon frames, in the scan's frame, for a local planner.",
        ),
    ] = False
    combine: CombineOpt = False
    no_combine: NoCombineOpt = False
    learn: LearnOpt = False
    grid: ModelGridOpt = None
    res: ModelResOpt = None
    moving_threshold: MovingOpt = None
    queue: Annotated[
        int,
        typer.Option(
            help="Scans kept while the model is busy; beyond them the oldest are dropped.", min=1
        ),
    ] = 10
    scan_qos: Annotated[
        str,
        typer.Option(
            help="QoS of the scan subscription: sensor (sensor data, best effort; matches any "
            "driver) or reliable."
        ),
    ] = "sensor"
    grid_qos: Annotated[
        str, typer.Option(help="QoS of the grid publishers: reliable or best-effort.")
    ] = "reliable"
    summary_every: Annotated[
        int, typer.Option(help="Scans between the latency summaries it logs.", min=1)
    ] = 100
    foxglove: Annotated[
        int | None,
        typer.Option(
            "--foxglove",
            metavar="PORT",
            help="Also serve scans and predictions to Foxglove on this port (ws://HOST:PORT, as "
            "`lidarflow live`; 0: any free port).",
            min=0,
            max=65535,
        ),
    ] = None
    host: Annotated[
        str, typer.Option(help="Address the Foxglove server listens on (with --foxglove).")
    ] = "127.0.0.1"
    verbose: Annotated[
        bool, typer.Option("--verbose", "-v", help="Also log every scan's latency.")
    ] = False
    threads: ThreadsOpt = DEFAULT_THREADS


@app.command()
@command_options(NodeOptions, omit=ROS2_ONLY)
def ros1(options: NodeOptions) -> None:
    """Run a ROS 1 node: per scan on --topic, publish the predicted next map (OccupancyGrid in
    the scan's frame) on /lidarflow/predicted and /lidarflow/decided, stamped with the time it
    predicts. Needs a roscore (ROS_MASTER_URI); stop it with Ctrl-C."""
    from lidarflow.live.ros1 import Ros1Node, check_master, import_ros

    _log_to_stderr("ros1", options.verbose)
    check_master(import_ros())  # before loading a model: say at once what is missing
    _serve("ros1", options, Ros1Node)


@app.command()
@command_options(NodeOptions)
def ros2(options: NodeOptions) -> None:
    """Run a ROS 2 node: per scan on --topic, publish the predicted next map (OccupancyGrid in
    the scan's frame) on /lidarflow/predicted and /lidarflow/decided, stamped with the time it
    predicts. Joins ROS_DOMAIN_ID's domain; stop it with Ctrl-C."""
    from lidarflow.live.ros2 import GRID_QOS, SCAN_QOS, Ros2Node, domain_id, import_ros2

    for name, value, choices in (("--scan-qos", options.scan_qos, SCAN_QOS),
                                 ("--grid-qos", options.grid_qos, GRID_QOS)):  # fmt: skip
        if value not in choices:
            raise typer.BadParameter(f"{value!r}: one of {', '.join(choices)}", param_hint=name)
    domain_id(os.environ)  # rclpy fails on a bad one without a word
    _log_to_stderr("ros2", options.verbose)
    import_ros2()  # before loading a model: say at once what is missing
    qos = {"scan_qos": options.scan_qos, "grid_qos": options.grid_qos}
    _serve("ros2", options, functools.partial(Ros2Node, **qos))


def _serve(kind: str, options: NodeOptions, node_type: Callable[..., RosNode]) -> None:
    """Run the node of ``node_type`` (the transport) on the live step the options ask for."""
    o = options
    step = _live_step(o)

    def make_node() -> RosNode:
        return node_type(step, o.topic, o.odom_topic, o.moving, queue=o.queue,
                         planner=o.planner_grid)  # fmt: skip

    _run(kind, step, make_node, o)


def _live_step(options: NodeOptions) -> LiveStep:
    """The node's step; a :class:`ModelError` where ``--moving`` asks for the moving cells of a
    model that estimates no flow."""
    from lidarflow.errors import ModelError
    from lidarflow.live.step import LiveStep
    from lidarflow.predict import Predictor
    from lidarflow.predict.moving import MOVING_THRESHOLD

    o = options
    predictor = Predictor(
        o.model,
        model_grid(o.model, o.grid, o.res),
        horizon=o.horizon,
        threads=o.threads or None,
        moving_threshold=MOVING_THRESHOLD if o.moving_threshold is None else o.moving_threshold,
        combine=combine_choice(o.combine, o.no_combine),
        learn=o.learn,
    )
    if o.moving and not predictor.backend.capabilities.flow:
        raise ModelError(
            f"--moving publishes a flow model's moving cells, and "
            f"{o.model or 'the bundled model'} estimates no flow; name a flow model with "
            "--model, or drop --moving"
        )
    return LiveStep(predictor, summary_every=o.summary_every)


def _run(kind: str, step: LiveStep, make_node: Callable[[], Any], options: NodeOptions) -> None:
    """Spin the node ``make_node`` builds, with the Foxglove server beside it where asked; the
    latency over all scans said last."""
    foxglove, topic = options.foxglove, options.topic
    with contextlib.ExitStack() as stack:
        if foxglove is not None:
            from lidarflow.live.foxglove import LiveServer

            predictor = step.predictor
            server = stack.enter_context(LiveServer(
                predictor.grid, host=options.host, port=foxglove, horizon=predictor.horizon,
                flow=predictor.backend.capabilities.flow, scan_topic=topic,
            ))  # fmt: skip
            step.sinks.append(server.publish_frame)
            typer.echo(f"lidarflow {kind}: serving Foxglove on {server.url}", err=True)
        node = make_node()
        node.start()
        try:
            node.spin()
        finally:
            if step.latency.all_ms:
                typer.echo(f"lidarflow {kind}: latency over {step.latency.describe()}", err=True)
            else:
                typer.echo(f"lidarflow {kind}: no scan arrived on {topic}", err=True)


def _log_to_stderr(kind: str, verbose: bool) -> None:
    """The node's log on stderr, one line a message, every scan's with ``verbose`` (not
    through rospy's logging, which it configures its own way)."""
    level = logging.DEBUG if verbose else logging.INFO
    logger = logging.getLogger("lidarflow.live")
    handler = logging.StreamHandler()
    handler.setFormatter(logging.Formatter(f"lidarflow {kind}: %(message)s"))
    logger.handlers = [handler]
    logger.setLevel(level)
    logger.propagate = False
