"""The sensor's own motion between consecutive frames, from a recording's poses.

``Recording.poses`` is ``(N, 3)`` ``(x, y, yaw)`` in a fixed frame (odometry), NaN where unknown.
The ego motion of frame ``t`` is the pose of frame ``t`` in the frame of ``t - 1``
(``relative(poses[t-1], poses[t])``: ``dx`` forward, ``dy`` left in metres, ``dyaw`` radians),
the convention of :mod:`lidarflow.ops.rigid`. Frame 0, and every frame whose own pose or whose
predecessor's pose is unknown, gets the identity motion and ``known = False``: a model then
simply does not compensate that step (what it does without odometry).

Poses are taken to be the sensor's; a bag's odometry is usually the robot base's, which differs
only by the lever arm of the sensor mount under rotation (a few centimetres per frame at most for
a scanner mounted near the rotation centre).
"""

from __future__ import annotations

import numpy as np

__all__ = ["metres_to_cells", "relative_motions"]


def relative_motions(
    poses: np.ndarray | None, n: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame ego motion ``(N, 3)`` float64 and whether it is known ``(N,)`` bool.

    ``poses=None`` (a recording without odometry) gives ``n`` identity motions, all unknown.

    >>> m, known = relative_motions(np.array([[0, 0, 0], [1, 0, np.pi / 2], [1, 1, np.pi / 2]]))
    >>> np.round(m, 6).tolist(), known.tolist()
    ([[0.0, 0.0, 0.0], [1.0, 0.0, 1.570796], [1.0, 0.0, 0.0]], [False, True, True])
    """
    if poses is None:
        if n is None:
            raise ValueError("relative_motions needs poses or the number of frames")
        return np.zeros((n, 3)), np.zeros(n, dtype=bool)
    poses = np.asarray(poses, dtype=np.float64)
    if poses.ndim != 2 or poses.shape[1] != 3:
        raise ValueError(f"poses must be (N, 3) (x, y, yaw), got {poses.shape}")
    motions = np.zeros_like(poses)
    known = np.zeros(len(poses), dtype=bool)
    if len(poses) < 2:
        return motions, known
    a, b = poses[:-1], poses[1:]
    ok = np.isfinite(a).all(axis=1) & np.isfinite(b).all(axis=1)
    c, s = np.cos(a[:, 2]), np.sin(a[:, 2])
    dx, dy = b[:, 0] - a[:, 0], b[:, 1] - a[:, 1]
    dyaw = np.remainder(b[:, 2] - a[:, 2] + np.pi, 2 * np.pi) - np.pi
    rel = np.stack([c * dx + s * dy, -s * dx + c * dy, dyaw], axis=1)
    motions[1:][ok] = rel[ok]
    known[1:] = ok
    return motions, known


def metres_to_cells(motions: np.ndarray, res: float) -> np.ndarray:
    """``(dx, dy)`` from metres to cells of size ``res``; ``dyaw`` unchanged (float32)."""
    out = np.asarray(motions, dtype=np.float64).copy()
    out[..., :2] /= res
    return out.astype(np.float32)
