"""The robot's poses in a bag: odometry (or pose) messages as planar poses, moved onto the scanner
by its mount in the bag's TF (:mod:`lidarflow.data.tf`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from lidarflow.data.cleaning import zero_stamps_filled
from lidarflow.data.messages import stamp_ns
from lidarflow.data.tf import TransformTree, compose_poses, mirrored, yaw_of

__all__ = ["PoseLog", "on_the_scanner", "pose_of"]


def pose_of(msg: Any) -> tuple[float, float, float]:
    """The planar pose ``(x, y, yaw)`` (metres, radians) of an Odometry or PoseStamped message
    (anything with ``pose.pose`` or ``pose`` holding ``position`` and ``orientation``)."""
    pose = msg.pose.pose if hasattr(msg.pose, "pose") else msg.pose
    return float(pose.position.x), float(pose.position.y), yaw_of(pose.orientation)


@dataclass
class PoseLog:
    """A bag's odometry messages as they are read, and ``body``, the child frame the poses are
    of (the first one named; ``""`` where none is)."""

    stamps: list[int] = field(default_factory=list)
    log_times: list[int] = field(default_factory=list)
    values: list[tuple[float, float, float]] = field(default_factory=list)
    body: str = ""

    def add(self, msg: Any, log_time: int) -> None:
        self.body = self.body or str(getattr(msg, "child_frame_id", "")).lstrip("/")
        self.stamps.append(stamp_ns(msg))
        self.log_times.append(int(log_time))
        self.values.append(pose_of(msg))

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(stamps, log times, poses (M, 3))`` as :func:`~lidarflow.data.sessions.in_sessions`
        takes them, zero header stamps filled as a scan's are."""
        logged = np.array(self.log_times, dtype=np.int64)
        return (
            zero_stamps_filled(np.array(self.stamps, dtype=np.int64), logged),
            logged,
            np.array(self.values, dtype=np.float64).reshape(-1, 3),
        )


def on_the_scanner(
    poses: np.ndarray, tree: TransformTree, body: str, frame_id: str
) -> tuple[np.ndarray, dict[str, Any]]:
    """``poses`` ``(N, 3)`` of the frame ``body`` moved onto the scanner's frame ``frame_id`` by
    its mount in ``tree``, and the metadata that say so: ``sensor_mount`` (``None``, the poses
    unchanged, where ``tree`` does not link the frames) and for a scanner mounted upside down
    ``sensor_upside_down``, its poses then mirrored so that their motions are its."""
    found = tree.mount(body, frame_id) if body and frame_id else None
    if found is None:
        return poses, {"sensor_mount": None}
    mount, upside_down = found
    poses = compose_poses(poses, mount)
    meta: dict[str, Any] = {"sensor_mount": [round(v, 6) for v in mount]}
    if upside_down:
        poses = mirrored(poses)
        meta["sensor_upside_down"] = True
    return poses, meta
