"""Ego-motion inputs of the streaming evaluation: per-frame motions of a recording, and the
baseline that only compensates the platform's own motion.

A method that takes the motion (``takes.motion``) is given, with each frame ``t``
(:class:`~lidarflow.predict.baselines.FrameInputs`), ``motion`` ``m_t``, the motion of frame ``t``
in frame ``t - 1`` in cells (:mod:`lidarflow.motion.odometry`; identity where a pose is unknown),
and ``next_motion`` ``m_{t+1}``, which is the future: only an oracle may use it. After a long step
in time (a gap, scans dropped) it also gets ``pace`` (typical step / this step,
:func:`lidarflow.motion.pacing.paces_after_long_steps`) to scale its guess of the next motion.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from lidarflow.data.blocks import Frames, streamed_maps
from lidarflow.data.recording import Recording
from lidarflow.errors import EvaluateError
from lidarflow.geometry import rigid_moved
from lidarflow.motion.icp import streamed_points
from lidarflow.motion.odometry import metres_to_cells, relative_motions
from lidarflow.motion.pacing import paced_motion
from lidarflow.motion.scanmatch import scan_motions
from lidarflow.predict.baselines import NOTHING_MORE, FrameInputs, Method, Takes
from lidarflow.scan import GridSpec

__all__ = ["CopyLastEgo", "recording_motions", "wants_motion"]


def wants_motion(methods: Sequence[Method]) -> list[str]:
    """Names of the methods that take the ego motion."""
    return [m.name for m in methods if m.takes.motion]


def recording_motions(
    recording: Recording,
    grid: GridSpec,
    methods: Sequence[Method],
    occupancy: Frames | None = None,
) -> np.ndarray | None:
    """``(N, 3)`` float32 motions in cells when some method wants them, else ``None``.

    For a recording with no pose at all, when every method that wants them may run without
    (``poses_optional``), the motions found by matching consecutive maps (``occupancy``, the
    recording's maps on ``grid``; :mod:`lidarflow.motion.scanmatch`), NaN where none was found
    (those steps are not compensated).

    Raises:
        EvaluateError: a method that needs them (no ``poses_optional``) and a recording with no
            pose at all (we fail rather than silently evaluate an ego-motion model without
            odometry).
    """
    users = wants_motion(methods)
    if not users:
        return None
    if not recording.has_poses:
        needing = [m for m in methods if m.takes.motion and not m.takes.poses_optional]
        if not needing:
            if occupancy is None:
                occupancy = streamed_maps(recording, grid)[0]
            return scan_motions(occupancy, streamed_points(recording), grid.res)
        users = [m.name for m in needing]
        source = recording.meta.get("source") or recording.meta.get("path") or "the recording"
        raise EvaluateError(
            f"{source}: no sensor poses, but {', '.join(users)} compensate(s) ego motion; "
            "convert the bag with --odom-topic (or simulate it), or evaluate a model trained "
            "without --ego-motion"
        )
    motions, _ = relative_motions(recording.poses, len(recording))
    return metres_to_cells(motions, grid.res)


class CopyLastEgo:
    """Copy the last map moved into the next sensor frame by the odometry, assuming the motion
    to the next frame equals the last one (constant velocity, causal); the oracle variant uses
    the true next motion. What ego-motion compensation alone buys, with no learned flow."""

    # without poses it is copy_last: never the reason to refuse one
    takes = Takes(motion=True, poses_optional=True)

    def __init__(self, oracle: bool = False) -> None:
        self.oracle = oracle
        self.name = "copy_last_ego_oracle" if oracle else "copy_last_ego"

    def reset(self) -> None:
        pass

    def update(
        self, occupancy: np.ndarray, visibility: np.ndarray, given: FrameInputs = NOTHING_MORE
    ) -> np.ndarray:
        motion, next_motion = given.motion, given.next_motion
        # after a long step the last motion spans it: the guess is scaled to one, as the models'
        guessed = paced_motion(motion, given.pace)
        m = next_motion if self.oracle else (motion if guessed is None else guessed)
        if m is None:
            return occupancy.astype(np.float32)
        return np.clip(rigid_moved(occupancy, m), 0.0, 1.0).astype(np.float32)
