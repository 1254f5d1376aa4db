"""The robot's poses in a bag: odometry (or pose) messages as planar poses.

Odometry reports the pose of its child frame (usually the robot base); the scans' poses are
those interpolated at the scan stamps (:func:`lidarflow.data.sessions.in_sessions`), then
moved onto the scanner by its mount in the bag's TF (:mod:`lidarflow.data.tf`).
"""

from __future__ import annotations

import math
from typing import Any

__all__ = ["pose_of"]


def pose_of(msg: Any) -> tuple[float, float, float]:
    """The planar pose ``(x, y, yaw)`` (metres, radians) of an Odometry or PoseStamped message
    (anything with ``pose.pose`` or ``pose``: ``position`` and an ``orientation`` quaternion);
    yaw is the rotation about z."""
    pose = msg.pose.pose if hasattr(msg.pose, "pose") else msg.pose
    q = pose.orientation
    yaw = math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))
    return float(pose.position.x), float(pose.position.y), yaw
