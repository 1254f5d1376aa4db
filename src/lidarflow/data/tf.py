"""The sensor's mount on the robot from a bag's TF, so odometry poses become sensor poses.

``sensor_pose = base_pose o mount``, with ``mount`` the planar pose ``(x, y, yaw)`` of the scan
frame in the odometry's child frame, read from ``/tf`` and ``/tf_static``; the first transform
seen for every (parent, child) pair is kept. A scanner mounted upside down sees the world
mirrored, which no ``(x, y, yaw)`` says: a mount also says whether it is flipped (the frame is
then the pose followed by ``y -> -y``), and the sensor's motions are the upright frame's
mirrored (:func:`mirrored`).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["TF_TYPE", "TransformTree", "compose_poses", "mirrored", "yaw_of"]

TF_TYPE = "tf2_msgs/msg/TFMessage"


def _frame(name: str) -> str:
    return str(name).lstrip("/")


def yaw_of(q: Any) -> float:
    """The rotation about z (radians) of a quaternion with ``x, y, z, w``: for a frame flipped
    upside down too, the bearing of its x axis in the plane."""
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


class TransformTree:
    """Planar transforms ``child -> (parent, x, y, yaw, flipped)`` gathered from TF messages."""

    def __init__(self) -> None:
        self.parent: dict[str, tuple[str, float, float, float, bool]] = {}

    def add(self, msg: Any) -> None:
        """Take the transforms of one ``tf2_msgs/TFMessage`` not seen before."""
        for tr in msg.transforms:
            child = _frame(tr.child_frame_id)
            if child in self.parent:
                continue
            t, q = tr.transform.translation, tr.transform.rotation
            # yaw_of reads the rotation matrix's first column, which gives the yaw of an upright
            # or a flipped frame alike (R = Rz(yaw) or Rz(yaw) diag(1, -1, -1)); R22 the z axis
            flipped = 1.0 - 2.0 * (q.x * q.x + q.y * q.y) < 0.0
            parent = _frame(tr.header.frame_id)
            self.parent[child] = (parent, float(t.x), float(t.y), yaw_of(q), flipped)

    def mount(self, base: str, frame: str) -> tuple[tuple[float, float, float], bool] | None:
        """``((x, y, yaw), flipped)`` of ``frame`` in ``base`` (flipped: ``frame`` is that pose
        followed by ``y -> -y``), or ``None`` when ``frame`` does not descend from ``base``."""
        base, frame = _frame(base), _frame(frame)
        pose, flipped = np.zeros(3), False
        for _ in range(64):  # TF trees are shallow; this also stops on a cycle
            if frame == base:
                return (float(pose[0]), float(pose[1]), float(pose[2])), flipped
            if frame not in self.parent:
                return None
            parent, x, y, yaw, link_flipped = self.parent[frame]
            if link_flipped:  # what lies below a flipped link is seen mirrored from above it
                pose, flipped = mirrored(pose[None])[0], not flipped
            pose = compose_poses(np.array([[x, y, yaw]]), pose)[0]
            frame = parent
        return None


def mirrored(poses: np.ndarray) -> np.ndarray:
    """``(x, -y, -yaw)``: poses (or motions) seen through the reflection ``y -> -y``."""
    return np.asarray(poses, dtype=np.float64) * np.array([1.0, -1.0, -1.0])


def compose_poses(poses: np.ndarray, offset: np.ndarray | tuple[float, float, float]) -> np.ndarray:
    """``poses (N, 3) o offset (3,)``: the pose of a frame mounted at ``offset`` on a body at
    each of ``poses``; NaN rows stay NaN.

    >>> compose_poses(np.array([[1.0, 0.0, math.pi / 2]]), (0.5, 0.0, 0.1)).round(3).tolist()
    [[1.0, 0.5, 1.671]]
    """
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    mx, my, myaw = (float(v) for v in np.asarray(offset, dtype=np.float64).reshape(3))
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    yaw = np.remainder(poses[:, 2] + myaw + math.pi, 2 * math.pi) - math.pi
    return np.stack([poses[:, 0] + c * mx - s * my, poses[:, 1] + s * mx + c * my, yaw], axis=1)
