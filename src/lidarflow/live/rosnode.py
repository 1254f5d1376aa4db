"""What the ROS 1 and ROS 2 nodes share: a scan message into the live step, the sensor's pose
from odometry and TF, and the step's grids out as ``nav_msgs/OccupancyGrid`` messages.

Both ROS generations give the same message fields; a subclass supplies where the client library
comes from, how stamps are read and written and how the node meets its peers.
"""

from __future__ import annotations

import logging
import threading
import time
from abc import ABC, abstractmethod
from typing import Any

import numpy as np

from lidarflow.errors import LidarflowError, PredictError, ScanError
from lidarflow.live.step import LiveFrame, LiveStep
from lidarflow.outputs.grids import GridLayout, grid_topics, prediction_grids
from lidarflow.scan import BeamGeometry, Scan

__all__ = ["RosNode"]

log = logging.getLogger("lidarflow.live")


class RosNode(ABC):
    """Scans and odometry in, grids out, whichever ROS carries them.

    Args:
        step: the per-scan step; the node appends :meth:`publish` to its sinks.
        topic: the LaserScan topic.
        odom_topic: a ``nav_msgs/Odometry`` topic for the sensor's poses, or ``None``.
        moving: also publish ``/lidarflow/moving`` (flow models).
        name: the node's name.
        queue: scans kept while the node is busy; beyond it the oldest are dropped
            (a node slower than its scanner falls behind by at most this many).
        planner: also publish the planner grid (:func:`lidarflow.outputs.grids.planner_topic`;
            :mod:`lidarflow.outputs.planner`).
    """

    SCAN_TYPE: str
    ODOM_TYPE: str

    def __init__(
        self,
        step: LiveStep,
        topic: str = "/scan",
        odom_topic: str | None = None,
        moving: bool = False,
        name: str = "lidarflow",
        queue: int = 10,
        planner: bool = False,
    ) -> None:
        from lidarflow.data.tf import TransformTree

        self.ros = self._import_ros()  # first: a missing ROS is said before anything is set up
        self.step, self.topic, self.odom_topic = step, topic, odom_topic
        self.moving, self.name, self.queue = moving, name, queue
        self.layout = GridLayout.of(step.predictor.grid)
        self.topics = grid_topics(step.predictor.horizon, moving, occupancy=False, planner=planner)
        self._publishers: dict[str, Any] = {}
        self._geometry: dict[tuple[float, ...], BeamGeometry] = {}
        self._tree = TransformTree()
        self._tf_lock = threading.Lock()
        self._odom: tuple[tuple[float, float, float], str] | None = None
        self._failure: LidarflowError | None = None
        self._warned: set[str] = set()
        step.sinks.append(self.publish)

    @staticmethod
    @abstractmethod
    def _import_ros() -> Any:
        """This ROS's client library and the message classes the node uses; a
        :class:`PredictError` naming how to install them where they are missing."""

    # ------------------------------------------------------------------ lifecycle
    @abstractmethod
    def start(self) -> None:
        """Meet the peers: the publishers first, so that no grid goes out unadvertised, then
        the subscriptions."""

    def spin(self, check_every_s: float = 2.0) -> None:
        """Run until Ctrl-C or SIGTERM (returns), ROS shuts the node down (returns), or a scan
        fails (raises its error); every ``check_every_s`` the graph is asked whether the topics
        carry the types the node expects. The node is closed on the way out."""
        next_check = 0.0
        try:
            while self._failure is None and self._running():
                if time.monotonic() >= next_check:
                    self._check_types()
                    next_check = time.monotonic() + check_every_s
                time.sleep(0.05)
        except KeyboardInterrupt:
            log.info("stopping")
        finally:
            self.close()
        if self._failure is not None:
            raise self._failure

    @abstractmethod
    def _running(self) -> bool:
        """Whether ROS still runs the node (not shut down from outside)."""

    def _check_types(self) -> None:
        """A :class:`PredictError` naming the option to fix where the scan or odometry topic
        carries another message type."""
        wanted = {self.topic: (self.SCAN_TYPE, "--topic")}
        if self.odom_topic:
            wanted[self.odom_topic] = (self.ODOM_TYPE, "--odom-topic")
        for topic, (msgtype, option) in wanted.items():
            resolved, carried = self._types_on(topic)
            for other in carried:
                if other != msgtype:
                    raise PredictError(
                        f"{resolved} carries {other}, not {msgtype}: name the right topic with "
                        f"{option}"
                    )

    @abstractmethod
    def _types_on(self, topic: str) -> tuple[str, list[str]]:
        """``topic``'s resolved name and the message types published on it."""

    @abstractmethod
    def close(self) -> None:
        """Leave the ROS graph."""

    # ------------------------------------------------------------------ in
    def _scan_in(self, msg: Any, stamp_ns: int, received: int) -> None:
        """One ``sensor_msgs/LaserScan`` (stamped ``stamp_ns``, arrived at ``received`` on
        :data:`lidarflow.live.step.clock_ns`) through the step; a failure is kept for the
        node's loop to raise, so that it stops rather than logs one error per scan."""
        if self._failure is not None:
            return
        frame_id = str(msg.header.frame_id).lstrip("/")
        try:
            scan = Scan(np.asarray(msg.ranges, dtype=np.float32),
                        self._beams(msg, len(msg.ranges)), stamp_ns)  # fmt: skip
        except ScanError as err:  # one malformed scan (a driver's first) is skipped
            self._warn_once("scan", f"{self.topic}: scan skipped ({err})")
            return
        try:
            self.step(scan, frame_id, received, self._pose(frame_id))
        except LidarflowError as err:
            self._failure = err
        except Exception as err:  # a bug: stop with it rather than log one per scan
            self._failure = PredictError(f"{type(err).__name__}: {err}")
            self._failure.__cause__ = err

    def _beams(self, msg: Any, count: int) -> BeamGeometry:
        key = (count, msg.angle_min, msg.angle_increment, msg.range_min, msg.range_max)
        geometry = self._geometry.get(key)
        if geometry is None:
            geometry = BeamGeometry(count, float(msg.angle_min), float(msg.angle_increment),
                                    float(msg.range_min), float(msg.range_max))  # fmt: skip
            self._geometry = {key: geometry}  # a scanner keeps its geometry: one is enough
        return geometry

    def _on_odom(self, msg: Any) -> None:
        from lidarflow.data.poses import pose_of  # the planar pose, as a bag's is read

        self._odom = (pose_of(msg), str(msg.child_frame_id).lstrip("/"))

    def _on_tf(self, msg: Any) -> None:
        with self._tf_lock:
            self._tree.add(msg)

    def _pose(self, frame_id: str) -> tuple[float, float, float] | None:
        """The scanner's pose: the latest odometry moved by the scanner's mount on the body
        odometry reports (``child_frame_id``), where TF has it; ``None`` without odometry."""
        from lidarflow.data.tf import compose_poses, mirrored

        if self._odom is None:
            return None
        pose, body = self._odom
        with self._tf_lock:
            found = self._tree.mount(body, frame_id) if body and frame_id else None
        if found is None:
            body = body or "(no child_frame_id)"
            self._warn_once(
                "mount", f"no TF from {body} to {frame_id}: odometry taken as the scanner's pose"
            )
            return pose
        mount, upside_down = found
        moved = compose_poses(np.asarray(pose)[None], mount)
        if upside_down:  # the scanner sees the world mirrored, and so moves in it
            moved = mirrored(moved)
        return (float(moved[0, 0]), float(moved[0, 1]), float(moved[0, 2]))

    def _warn_once(self, key: str, text: str) -> None:
        if key not in self._warned:
            self._warned.add(key)
            log.warning(text)

    # ------------------------------------------------------------------ out
    def publish(self, frame: LiveFrame) -> None:
        """The node's sink: the frame's grids on their topics, in the scan's frame."""
        grids = prediction_grids(frame.prediction, self.topics)
        if self.moving and frame.prediction.moving is None:
            self._warn_once("moving", "this model has no flow: nothing on /lidarflow/moving")
        for grid in grids:
            msg = self._message(grid.data, grid.stamp_ns, grid.scan_stamp_ns, frame.frame_id)
            self._publishers[grid.topic].publish(msg)

    def _message(self, data: np.ndarray, stamp_ns: int, scan_ns: int, frame_id: str) -> Any:
        """An ``OccupancyGrid`` of this ROS: ``data`` in the node's layout, stamped ``stamp_ns``,
        ``map_load_time`` the scan's stamp ``scan_ns``."""
        msg = self.ros.OccupancyGrid()
        msg.header.stamp = self._time(stamp_ns)
        msg.header.frame_id = frame_id
        info = msg.info
        info.map_load_time = self._time(scan_ns)
        # plain Python numbers: rclpy checks each field's type
        info.resolution = float(self.layout.resolution)
        info.width, info.height = int(self.layout.width), int(self.layout.height)
        info.origin.position.x = float(self.layout.origin_x)
        info.origin.position.y = float(self.layout.origin_y)
        info.origin.orientation.w = 1.0
        msg.data = self._cells(data)
        return msg

    @abstractmethod
    def _time(self, ns: int) -> Any:
        """This ROS's ``Time`` message of a stamp in nanoseconds."""

    @abstractmethod
    def _cells(self, data: np.ndarray) -> Any:
        """An ``OccupancyGrid``'s ``data`` field of int8 cells, as this ROS packs it fastest."""
