"""``lidarflow ros2``: the ROS 1 node's counterpart over ROS 2 (:mod:`lidarflow.live.ros1`;
shared: :class:`lidarflow.live.rosnode.RosNode`).

QoS: scans with the sensor-data profile (best effort, which matches best-effort and reliable
drivers alike), grids reliable (a planner must not miss one), both configurable;
``/tf_static`` transient local, as its publishers latch it. rclpy comes from the ``ros2`` extra
(ROS 2 Jazzy's wheels, which lack ``tf2_msgs``: then no TF, the odometry taken as the
scanner's pose) or a sourced ROS 2 installation for this Python. Setup: docs/guide/robot.md.
"""

from __future__ import annotations

import array
import contextlib
import logging
import threading
from collections.abc import Mapping
from dataclasses import dataclass
from types import ModuleType
from typing import Any

import numpy as np

from lidarflow.errors import PredictError
from lidarflow.live.rosnode import RosNode
from lidarflow.live.step import LiveStep, clock_ns

__all__ = [
    "DOMAIN_IDS",
    "GRID_QOS",
    "ROS2_EXTRA",
    "SCAN_QOS",
    "Ros2",
    "Ros2Node",
    "domain_id",
    "import_ros2",
]

log = logging.getLogger("lidarflow.live")

#: How a user gets rclpy for this Python (named in the error where it is missing).
ROS2_EXTRA = 'pip install "lidarflow[ros2]"'
#: ``--scan-qos`` choices: sensor data (best effort) or reliable.
SCAN_QOS = ("sensor", "reliable")
#: ``--grid-qos`` choices.
GRID_QOS = ("reliable", "best-effort")
#: The domains ``ROS_DOMAIN_ID`` may name (ROS 2's range: 232 is the last that maps to UDP
#: ports on every platform).
DOMAIN_IDS = range(233)


def domain_id(environ: Mapping[str, str]) -> int | None:
    """The ROS domain ``environ``'s ``ROS_DOMAIN_ID`` names: ``None`` where it is unset or
    empty (ROS 2's default domain, 0), else an integer in :data:`DOMAIN_IDS`.

    Raises :class:`PredictError` (one line with what was given and the valid range) for
    anything else, which rclpy would otherwise fail on without a word.

    >>> domain_id({"ROS_DOMAIN_ID": " 42 "}), domain_id({})
    (42, None)
    """
    given = environ.get("ROS_DOMAIN_ID", "")
    digits = given.strip()
    if not digits:
        return None
    if not (digits.isascii() and digits.isdigit() and int(digits) in DOMAIN_IDS):
        raise PredictError(
            f"ROS_DOMAIN_ID={given!r} is no ROS 2 domain: set it to an integer from "
            f"{DOMAIN_IDS.start} to {DOMAIN_IDS.stop - 1}, or unset it for domain 0"
        )
    return int(digits)


@dataclass(frozen=True)
class Ros2:
    """rclpy and the message classes the node uses (``TFMessage`` ``None`` where missing)."""

    rclpy: ModuleType
    qos: ModuleType
    LaserScan: type
    Odometry: type
    OccupancyGrid: type
    Time: type
    TFMessage: type | None


def import_ros2() -> Ros2:
    """rclpy and the messages, from wherever this Python finds them.

    Raises :class:`PredictError` (one line saying how to get them) where they are missing.
    """
    try:
        import rclpy
        import rclpy.qos
        from builtin_interfaces.msg import Time
        from nav_msgs.msg import OccupancyGrid, Odometry
        from sensor_msgs.msg import LaserScan
    except ImportError as err:  # rclpy's C part missing for this Python is an ImportError too
        raise PredictError(
            f"ROS 2 is not installed for this Python ({err}): {ROS2_EXTRA} (ROS 2 Jazzy's "
            "wheels), or source a ROS 2 installation built for this Python version"
        ) from err
    try:
        from tf2_msgs.msg import TFMessage
    except ImportError:  # the PyPI wheels lack it (see the module's docstring)
        TFMessage = None
    return Ros2(rclpy, rclpy.qos, LaserScan, Odometry, OccupancyGrid, Time, TFMessage)


class Ros2Node(RosNode):
    """The ROS 2 side of the node: :class:`lidarflow.live.rosnode.RosNode`'s arguments
    (``queue`` the history depth of the scan subscription and the grid publishers), and by
    keyword ``scan_qos``, one of :data:`SCAN_QOS`, and ``grid_qos``, one of :data:`GRID_QOS`."""

    ros: Ros2
    SCAN_TYPE = "sensor_msgs/msg/LaserScan"
    ODOM_TYPE = "nav_msgs/msg/Odometry"
    _import_ros = staticmethod(import_ros2)

    def __init__(
        self, step: LiveStep, *args: Any, scan_qos: str = "sensor", grid_qos: str = "reliable",
        **kwargs: Any,
    ) -> None:  # fmt: skip
        if scan_qos not in SCAN_QOS or grid_qos not in GRID_QOS:
            raise PredictError(
                f"scan QoS {scan_qos!r} or grid QoS {grid_qos!r} unknown: "
                f"scans {'/'.join(SCAN_QOS)}, grids {'/'.join(GRID_QOS)}"
            )
        super().__init__(step, *args, **kwargs)
        self.scan_qos, self.grid_qos = scan_qos, grid_qos
        self._context: Any = None
        self._node: Any = None
        self._executor: Any = None
        self._thread: threading.Thread | None = None

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        """Join the domain (publishers first, then the subscriptions); callbacks run on an
        executor thread of their own."""
        rclpy, qos = self.ros.rclpy, self.ros.qos
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.signals import SignalHandlerOptions

        self._context = rclpy.Context()
        # signals stay the CLI's (Ctrl-C and SIGTERM stop spin); ROS arguments are not read
        # from lidarflow's own command line
        rclpy.init(args=[], context=self._context,
                   signal_handler_options=SignalHandlerOptions.NO)  # fmt: skip
        node = self._node = rclpy.create_node(self.name, context=self._context)
        reliability = (qos.ReliabilityPolicy.RELIABLE if self.grid_qos == "reliable"
                       else qos.ReliabilityPolicy.BEST_EFFORT)  # fmt: skip
        grids = qos.QoSProfile(depth=self.queue, reliability=reliability)
        for topic in self.topics:
            self._publishers[topic] = node.create_publisher(self.ros.OccupancyGrid, topic, grids)
        if self.odom_topic:
            node.create_subscription(self.ros.Odometry, self.odom_topic, self._on_odom, 1)
            self._subscribe_tf(node, qos)
        scans = qos.QoSProfile(depth=self.queue, reliability=(
            qos.ReliabilityPolicy.BEST_EFFORT if self.scan_qos == "sensor"
            else qos.ReliabilityPolicy.RELIABLE))  # fmt: skip
        if self.scan_qos == "sensor":  # the rest of the sensor-data profile, the depth ours
            scans.durability = qos.qos_profile_sensor_data.durability
        node.create_subscription(self.ros.LaserScan, self.topic, self._on_scan, scans)
        self._executor = SingleThreadedExecutor(context=self._context)
        self._executor.add_node(node)
        self._thread = threading.Thread(target=self._spin, name="rclpy", daemon=True)
        self._thread.start()
        odom = f", poses from {self.odom_topic}" if self.odom_topic else ""
        log.info("%s in ROS domain %d: scans from %s (%s QoS)%s; publishing %s (%s)",
                 node.get_fully_qualified_name(), self._context.get_domain_id(),
                 node.resolve_topic_name(self.topic), self.scan_qos, odom,
                 ", ".join(self.topics), self.grid_qos)  # fmt: skip

    def _subscribe_tf(self, node: Any, qos: ModuleType) -> None:
        if self.ros.TFMessage is None:
            self._warn_once(
                "mount",
                "tf2_msgs is not installed (the ROS 2 wheels lack it; a sourced ROS 2 has it): "
                "no /tf, odometry taken as the scanner's pose",
            )
            return
        node.create_subscription(self.ros.TFMessage, "/tf", self._on_tf, 100)
        static = qos.QoSProfile(depth=100, durability=qos.DurabilityPolicy.TRANSIENT_LOCAL)
        node.create_subscription(self.ros.TFMessage, "/tf_static", self._on_tf, static)

    def _spin(self) -> None:
        from rclpy.executors import ExternalShutdownException

        # the context shut down: the node is stopping
        with contextlib.suppress(ExternalShutdownException):
            self._executor.spin()

    def _running(self) -> bool:
        return self._context.ok()

    def close(self) -> None:
        """Leave the domain: the executor stopped, the node destroyed, the context shut down."""
        if self._context is None:
            return
        self._executor.shutdown(timeout_sec=5)
        self._node.destroy_node()
        if self._context.ok():
            self._context.try_shutdown()
        if self._thread is not None:
            self._thread.join(5)
        self._context = None

    def _types_on(self, topic: str) -> tuple[str, list[str]]:
        resolved = self._node.resolve_topic_name(topic)
        infos = self._node.get_publishers_info_by_topic(resolved)
        return resolved, [info.topic_type for info in infos]

    # ------------------------------------------------------------------ in
    def _on_scan(self, msg: Any) -> None:
        received = clock_ns()
        stamp = msg.header.stamp
        self._scan_in(msg, int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec), received)

    # ------------------------------------------------------------------ out
    def _time(self, ns: int) -> Any:
        sec, nanosec = divmod(int(ns), 1_000_000_000)
        return self.ros.Time(sec=sec, nanosec=nanosec)

    def _cells(self, data: np.ndarray) -> Any:
        # an int8 array.array: rclpy takes it as it is, where a list has every element checked
        return array.array("b", np.ascontiguousarray(data, dtype=np.int8).tobytes())
