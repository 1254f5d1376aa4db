"""Predictions served live to Foxglove over its WebSocket protocol (the ``foxglove-sdk``).

:meth:`LiveServer.publish` takes a scan and the :class:`~lidarflow.predict.Predictor`'s
prediction for it, from any loop (``lidarflow live`` replays a bag; a ROS node feeds it), and
sends in Foxglove's own protobuf schemas: the scan (``foxglove.LaserScan``), the grids of
:func:`lidarflow.outputs.grids.prediction_grids` (``foxglove.Grid``, laid out and stamped as the
OccupancyGrids are) and the forward flow as an ``rgb8`` colour wheel (``foxglove.RawImage``,
forward up). Only channels a client subscribes to are built and sent; every message of one scan
is logged at the scan's stamp. The SDK listens on localhost behind
:class:`~lidarflow.live.front.Front`. Topics and schemas: docs/guide/live.md.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any

import foxglove
import numpy as np
from foxglove.channels import GridChannel, LaserScanChannel, RawImageChannel
from foxglove.messages import (
    Grid,
    LaserScan,
    PackedElementField,
    PackedElementFieldNumericType,
    Pose,
    Quaternion,
    RawImage,
    Timestamp,
    Vector2,
    Vector3,
)

from lidarflow.errors import PredictError
from lidarflow.flowcolor import flow_to_rgb
from lidarflow.live.front import Front
from lidarflow.outputs.grids import (
    FLOW_RGB_FULL_CELLS,
    FLOW_RGB_TOPIC,
    OutGrid,
    grid_topics,
    prediction_grids,
)
from lidarflow.scan import GridSpec, Scan

if TYPE_CHECKING:
    from lidarflow.live.step import LiveFrame
    from lidarflow.predict.predictor import Prediction

__all__ = ["DEFAULT_PORT", "LiveServer"]

#: Foxglove's own default: its "Open connection" dialog offers ``ws://localhost:8765``.
DEFAULT_PORT = 8765
#: How long :meth:`LiveServer.close` waits at most for what is queued to reach the clients.
DRAIN_S = 2.0
#: Silence from the SDK that says it has written what was published (a scan is well under it).
QUIET_S = 0.05
#: The field a grid's cells carry (int8: probability x 100, -1 unknown, as OccupancyGrid).
GRID_FIELD = "occupancy"


def _stamp(ns: int) -> Timestamp:
    return Timestamp(int(ns // 1_000_000_000), int(ns % 1_000_000_000))


class LiveServer:
    """A Foxglove WebSocket server for one scan stream's predictions.

    ``with LiveServer(predictor.grid, "laser", horizon=predictor.horizon) as server:
    server.publish(scan, predictor.update(scan))``. ``horizon`` and ``flow`` (a model with flow:
    moving cells and the flow image) fix the topics advertised to a client as it connects.
    ``port`` 0 takes a free one (:attr:`port`). A taken port raises
    :class:`~lidarflow.errors.PredictError`.
    """

    def __init__(
        self,
        grid: GridSpec,
        frame_id: str = "laser",
        *,
        host: str = "127.0.0.1",
        port: int = DEFAULT_PORT,
        horizon: int = 1,
        flow: bool = True,
        scan_topic: str = "/scan",
        name: str = "lidarflow",
    ) -> None:
        self.grid = grid
        self.frame_id = frame_id
        self.horizon = horizon
        self.host = host
        # a context of its own: two servers in one process (tests) never share channels
        self._context = foxglove.Context()
        try:
            self._front = Front(host, port)
        except OSError as err:
            raise PredictError(
                f"cannot serve on {host}:{port}: {err.strerror or err} (another server there? "
                "pick another --port)"
            ) from err
        try:  # the SDK on localhost, behind the front (lidarflow.live.front says why)
            self._server = foxglove.start_server(
                name=name, host="127.0.0.1", port=0, context=self._context
            )
        except RuntimeError as err:  # the SDK's one error type; its text names the cause
            self._front.close(0.0)
            raise PredictError(f"cannot start the Foxglove server: {err}") from err
        self._front.start(self._server.port)
        self._scan = LaserScanChannel(scan_topic, context=self._context)
        self._grids = {
            topic: GridChannel(topic, context=self._context)
            for topic in grid_topics(horizon, moving=flow)
        }
        self._flow = RawImageChannel(FLOW_RGB_TOPIC, context=self._context) if flow else None
        # the grid's pose: the corner of cell (0, 0) in the scan's frame (design notes §8)
        self._pose = Pose(
            position=Vector3(x=0.0, y=-grid.width / 2 * grid.res, z=0.0),
            orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0),
        )
        self._fields = [
            PackedElementField(name=GRID_FIELD, offset=0, type=PackedElementFieldNumericType.Int8)
        ]
        self._closed = False
        self._last_sent = (-1, 0)  # the last publish's log time and the messages it logged

    # ------------------------------------------------------------------ lifecycle
    @property
    def port(self) -> int:
        """The port served on (the one the system picked where 0 was asked for)."""
        return self._front.port

    @property
    def url(self) -> str:
        """What to open in Foxglove ("Open connection" > "Foxglove WebSocket")."""
        host = f"[{self.host}]" if ":" in self.host else self.host  # an IPv6 address
        return f"ws://{host}:{self.port}"

    def _channels(self) -> list[Any]:
        return [self._scan, *self._grids.values(), *([self._flow] if self._flow else [])]

    @property
    def topics(self) -> list[str]:
        """Every topic served, the scan's first."""
        return [channel.topic() for channel in self._channels()]

    @property
    def subscribed(self) -> list[str]:
        """The topics some client subscribes to now."""
        return [channel.topic() for channel in self._channels() if channel.has_sinks()]

    def close(self) -> None:
        """Stop serving: what was published reaches the clients connected (:data:`DRAIN_S` at
        most), then they are disconnected with 1001, "going away". Closing twice is harmless."""
        if self._closed:
            return
        self._closed = True
        # the SDK drops at stop() what it has not yet written: let it write first
        self._front.wait_relayed(*self._last_sent, QUIET_S, DRAIN_S)
        for channel in self._channels():
            channel.close()
        self._server.stop()
        self._front.close(DRAIN_S)

    def __enter__(self) -> LiveServer:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    # ------------------------------------------------------------------ messages
    def publish(self, scan: Scan, prediction: Prediction, log_time_ns: int | None = None) -> None:
        """Send ``scan`` and what was predicted from it to the clients subscribed; logged at
        ``log_time_ns`` (default: the scan's stamp, else now for a scan without one)."""
        if self._closed:
            raise PredictError("the live server is closed: nothing can be published")
        at = log_time_ns if log_time_ns is not None else scan.stamp_ns or time.time_ns()
        if len(prediction.horizon) != self.horizon:
            raise PredictError(
                f"a prediction {len(prediction.horizon)} frames ahead, but the server was made "
                f"for {self.horizon}: give it the Predictor's horizon"
            )
        sent = 0
        if self._scan.has_sinks():
            self._scan.log(self._laser_scan(scan), log_time=at)
            sent += 1
        watched = {topic for topic, channel in self._grids.items() if channel.has_sinks()}
        for out in prediction_grids(prediction, watched):
            self._grids[out.topic].log(self._grid_message(out), log_time=at)
            sent += 1
        flow = prediction.forward_flow
        if self._flow is not None and flow is not None and self._flow.has_sinks():
            self._flow.log(self._flow_image(flow, prediction.stamp_ns or at), log_time=at)
            sent += 1
        self._last_sent = (at, sent)

    def publish_frame(self, frame: LiveFrame) -> None:
        """:meth:`publish` as a sink of :class:`~lidarflow.live.step.LiveStep` (the ROS node's
        ``--foxglove``): the frame's scan and prediction, in the frame's own scan frame."""
        self.frame_id = frame.frame_id
        self.publish(frame.scan, frame.prediction)

    def _laser_scan(self, scan: Scan) -> LaserScan:
        g = scan.geometry
        return LaserScan(
            timestamp=_stamp(scan.stamp_ns),
            frame_id=self.frame_id,
            pose=Pose(position=Vector3(), orientation=Quaternion(w=1.0)),
            start_angle=g.angle_min,
            end_angle=g.angle_min + g.angle_increment * (g.count - 1),
            ranges=np.asarray(scan.ranges, np.float64).tolist(),
        )

    def _grid_message(self, out: OutGrid) -> Grid:
        if out.data.size != self.grid.height * self.grid.width:
            raise PredictError(f"a map of {out.data.size} cells does not fit the grid {self.grid}")
        return Grid(
            timestamp=_stamp(out.stamp_ns),
            frame_id=self.frame_id,
            pose=self._pose,
            column_count=self.grid.height,  # cells along x: the map's rows, far edge last
            cell_size=Vector2(x=self.grid.res, y=self.grid.res),
            row_stride=self.grid.height,
            cell_stride=1,
            fields=self._fields,
            data=out.data.tobytes(),
        )

    def _flow_image(self, flow: np.ndarray, stamp_ns: int) -> RawImage:
        rgb = np.ascontiguousarray(flow_to_rgb(flow, FLOW_RGB_FULL_CELLS))
        height, width, _ = rgb.shape
        return RawImage(
            timestamp=_stamp(stamp_ns),
            frame_id=self.frame_id,
            width=width,
            height=height,
            encoding="rgb8",
            step=width * 3,
            data=rgb.tobytes(),
        )
