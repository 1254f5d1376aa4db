"""Ego-motion inputs of the streaming evaluation: per-frame motions of a recording.

A method with ``takes.motion`` gets with frame ``t`` (:class:`~lidarflow.baselines.FrameInputs`)
``motion``, frame ``t`` in frame ``t - 1`` in cells (:mod:`lidarflow.motion.odometry`), and
``next_motion``, the future that only an oracle may use; after a long step in time also
``pace`` (:func:`lidarflow.motion.pacing.paces_after_long_steps`).
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

__all__ = ["recording_motions"]


def recording_motions(
    recording: Recording,
    grid: GridSpec,
    methods: Sequence[Method],
    occupancy: Frames | None = None,
) -> np.ndarray | None:
    """``(N, 3)`` float32 motions in cells when some method wants them, else ``None``. On a
    recording without poses, when every such method is ``poses_optional``, the motions matched
    between its maps ``occupancy`` on ``grid`` (NaN where none was found); otherwise raises
    :class:`EvaluateError` rather than evaluate an ego-motion model uncompensated."""
    if not any(m.takes.motion for m in methods):
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
