"""The node's poses: odometry moved to the scanner by its mount from TF, with ROS 1's own
message classes (rospy's genpy messages, as the node receives them). No master needed."""

from __future__ import annotations

import math
import subprocess
import sys

import pytest

from lidarflow.live.step import LiveStep
from lidarflow.scan import GridSpec
from tests.live.rosmaster import require_ros


class GridOnly:
    """What the node reads of a Predictor before any scan comes."""

    grid = GridSpec()
    horizon = 1


@pytest.fixture
def node():
    require_ros()
    from lidarflow.live.ros1 import Ros1Node

    return Ros1Node(LiveStep(GridOnly()), "/scan", "/odom")


def odometry(ros, x: float, y: float, yaw: float, child: str = "base_link"):
    msg = ros.Odometry()
    msg.child_frame_id = child
    msg.pose.pose.position.x, msg.pose.pose.position.y = x, y
    msg.pose.pose.orientation.z, msg.pose.pose.orientation.w = math.sin(yaw / 2), math.cos(yaw / 2)
    return msg


def mount(ros, parent: str, child: str, x: float, yaw: float, upside_down: bool = False):
    from geometry_msgs.msg import TransformStamped

    t = TransformStamped()
    t.header.frame_id, t.child_frame_id = parent, child
    t.transform.translation.x = x
    q = t.transform.rotation
    if upside_down:  # rolled by 180 degrees, then turned by yaw
        q.x, q.y = math.cos(yaw / 2), math.sin(yaw / 2)
    else:
        q.z, q.w = math.sin(yaw / 2), math.cos(yaw / 2)
    return ros.TFMessage(transforms=[t])


def test_odometry_is_moved_to_the_scanner_by_its_mount(node):
    assert node._pose("laser") is None  # no odometry yet
    node._on_odom(odometry(node.ros, 2.0, 3.0, math.pi / 2))
    assert node._pose("laser") == pytest.approx((2.0, 3.0, math.pi / 2))  # no TF: as it is
    node._on_tf(mount(node.ros, "base_link", "laser", 1.0, math.pi / 4))
    assert node._pose("/laser") == pytest.approx((2.0, 4.0, 3 * math.pi / 4))  # 1 m ahead


def test_an_upside_down_scanner_moves_in_the_mirrored_world(node):
    node._on_tf(mount(node.ros, "base_link", "laser", 0.0, 0.0, upside_down=True))
    node._on_odom(odometry(node.ros, 1.0, 2.0, 0.3))
    assert node._pose("laser") == pytest.approx((1.0, -2.0, -0.3))


def test_the_live_modules_do_not_import_torch():
    # the node must run on the core install, without PyTorch (issue 37)
    from tests.without_torch import PRELUDE

    modules = "lidarflow.live.ros1, lidarflow.live.step, lidarflow.live.foxglove, lidarflow.cli"
    done = subprocess.run(
        [sys.executable, "-c", PRELUDE + f"import {modules}"],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-1500:]
