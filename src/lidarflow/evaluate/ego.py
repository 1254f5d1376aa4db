"""Ego-motion inputs of the streaming evaluation: per-frame motions of a recording (the
baseline that only compensates them is :class:`lidarflow.baselines.CopyLastEgo`).

A method that takes the motion (``takes.motion``) is given, with each frame ``t``
(:class:`~lidarflow.baselines.FrameInputs`), ``motion`` ``m_t``, the motion of frame ``t``
in frame ``t - 1`` in cells (:mod:`lidarflow.motion.odometry`; identity where a pose is unknown),
and ``next_motion`` ``m_{t+1}``, which is the future: only an oracle may use it. After a long step
in time (a gap, scans dropped) it also gets ``pace`` (typical step / this step,
:func:`lidarflow.motion.pacing.paces_after_long_steps`) to scale its guess of the next motion.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from lidarflow.baselines import Method
from lidarflow.data.blocks import Frames, streamed_maps
from lidarflow.data.recording import Recording
from lidarflow.errors import EvaluateError
from lidarflow.motion.icp import streamed_points
from lidarflow.motion.odometry import metres_to_cells, relative_motions
from lidarflow.motion.scanmatch import scan_motions
from lidarflow.scan import GridSpec

__all__ = ["recording_motions", "wants_motion"]


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
