"""``lidarflow ros1``: a live ROS 1 node predicting the next maps of a LaserScan topic.

Per scan it publishes, in the scan's frame, the OccupancyGrids of
:mod:`lidarflow.outputs.grids`; with an odometry topic an ego-motion model gets the sensor's
pose (:class:`lidarflow.live.rosnode.RosNode`, shared with ROS 2). ROS 1 comes from Debian's
packages (:data:`DEBIAN_PACKAGES`) for the system's Python 3; :func:`import_ros` appends their
folder to ``sys.path``, so this environment's own packages, NumPy among them, still come first.
Topics and setup: docs/guide/robot.md.
"""

from __future__ import annotations

import importlib
import logging
import socket
import sys
from dataclasses import dataclass
from types import ModuleType
from typing import Any

import numpy as np

from lidarflow.errors import PredictError
from lidarflow.live.rosnode import RosNode
from lidarflow.live.step import clock_ns

__all__ = ["DEBIAN_PACKAGES", "Ros", "Ros1Node", "check_master", "import_ros"]

log = logging.getLogger("lidarflow.live")

#: What Debian (bookworm and later) installs ROS 1 with for this node: roscore, rospy, rosbag
#: and the message packages it speaks.
DEBIAN_PACKAGES = "ros-core python3-rospy python3-sensor-msgs python3-nav-msgs python3-tf2-msgs"
#: Where Debian's Python packages (rospy, genpy, the messages) live.
DIST_PACKAGES = "/usr/lib/python3/dist-packages"


@dataclass(frozen=True)
class Ros:
    """rospy and the message classes the node uses."""

    rospy: ModuleType
    rosgraph: ModuleType
    LaserScan: type
    Odometry: type
    OccupancyGrid: type
    TFMessage: type


def import_ros() -> Ros:
    """rospy and the messages, from this environment or else from Debian's system folder.

    Raises :class:`PredictError` (one line naming the apt packages) where they are missing.
    """
    try:
        return _import_ros()
    except ImportError as err:
        missing = err
    if DIST_PACKAGES not in sys.path:
        sys.path.append(DIST_PACKAGES)  # appended: this environment's NumPy still wins
        importlib.invalidate_caches()
        try:
            return _import_ros()
        except ImportError as err:
            missing = err
    version = ".".join(map(str, sys.version_info[:2]))
    raise PredictError(
        f"ROS 1 is not installed for this Python ({missing}); on Debian: sudo apt-get install "
        f"{DEBIAN_PACKAGES} (for Debian's python3, whose version this {version} must match)"
    ) from missing


def _import_ros() -> Ros:
    import rosgraph
    import rospy
    from nav_msgs.msg import OccupancyGrid, Odometry
    from sensor_msgs.msg import LaserScan
    from tf2_msgs.msg import TFMessage

    return Ros(rospy, rosgraph, LaserScan, Odometry, OccupancyGrid, TFMessage)


def check_master(ros: Ros, timeout_s: float = 3.0) -> None:
    """Stop with one line where the ROS master of ``ROS_MASTER_URI`` does not answer within
    ``timeout_s`` (rospy itself would wait for one forever, saying nothing useful)."""
    previous = socket.getdefaulttimeout()
    socket.setdefaulttimeout(timeout_s)
    try:
        online = bool(ros.rosgraph.is_master_online())
    finally:
        socket.setdefaulttimeout(previous)
    if not online:
        uri = ros.rosgraph.get_master_uri()
        raise PredictError(f"no ROS master at {uri}: start roscore, or set ROS_MASTER_URI")


class Ros1Node(RosNode):
    """The ROS 1 side of the node: rospy's scans and odometry in, grids out (the arguments:
    :class:`lidarflow.live.rosnode.RosNode`'s)."""

    ros: Ros
    SCAN_TYPE = "sensor_msgs/LaserScan"
    ODOM_TYPE = "nav_msgs/Odometry"
    _import_ros = staticmethod(import_ros)

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        """Register with the master: publishers first, then the subscribers."""
        rospy = self.ros.rospy
        check_master(self.ros)
        # signals stay the CLI's (Ctrl-C and SIGTERM stop spin); remappings are not read from
        # lidarflow's own command line
        rospy.init_node(self.name, argv=[], disable_signals=True)
        for topic in self.topics:
            self._publishers[topic] = rospy.Publisher(
                topic, self.ros.OccupancyGrid, queue_size=self.queue
            )
        if self.odom_topic:
            rospy.Subscriber(self.odom_topic, self.ros.Odometry, self._on_odom, queue_size=1)
            rospy.Subscriber("/tf", self.ros.TFMessage, self._on_tf, queue_size=100)
            rospy.Subscriber("/tf_static", self.ros.TFMessage, self._on_tf, queue_size=100)
        rospy.Subscriber(self.topic, self.ros.LaserScan, self._on_scan, queue_size=self.queue)
        odom = f", poses from {self.odom_topic}" if self.odom_topic else ""
        uri = self.ros.rosgraph.get_master_uri()
        log.info("%s at %s: scans from %s%s; publishing %s", rospy.get_name(), uri, self.topic,
                 odom, ", ".join(self.topics))  # fmt: skip

    def _running(self) -> bool:
        return not self.ros.rospy.is_shutdown()

    def close(self) -> None:
        """Leave the ROS graph; rospy's node does not start again in this process."""
        self.ros.rospy.signal_shutdown("lidarflow stopped")

    def _types_on(self, topic: str) -> tuple[str, list[str]]:
        resolved = self.ros.rospy.resolve_name(topic)
        try:
            published = dict(self.ros.rospy.get_published_topics())
        except Exception:  # the master gone for a moment: rospy retries, and so do we
            return resolved, []
        return resolved, [published[resolved]] if resolved in published else []

    # ------------------------------------------------------------------ in
    def _on_scan(self, msg: Any) -> None:
        self._scan_in(msg, int(msg.header.stamp.to_nsec()), clock_ns())

    # ------------------------------------------------------------------ out
    def _time(self, ns: int) -> Any:
        return self.ros.rospy.Time(*divmod(int(ns), 1_000_000_000))

    def _cells(self, data: np.ndarray) -> Any:
        # a list: genpy packs a list of ints 3x faster than a NumPy array's elements
        return data.tolist()
