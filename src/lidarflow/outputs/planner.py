"""The planner grid: the occupancy a local planner should keep away from over the whole horizon,
as one map in the frame of the scan it was made from (docs/guide/planners.md).

Per cell, the largest predicted probability over ``k = 1 .. K`` x 100 (0..100); -1 where the
scan did not see the cell and no step decides it occupied, or no step's map covers it. Each
step's map lies in the sensor frame ``k`` frames ahead (``Prediction.ahead_motion`` repeated)
and is moved back into the scan's frame before the maximum, so that a cell is one place on the
ground.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from lidarflow.geometry import Sampler, rigid_positions
from lidarflow.outputs.grids import grid_values
from lidarflow.tracking import composed_motion

if TYPE_CHECKING:
    from lidarflow.predict.predictor import Prediction

__all__ = ["planner_grid", "steps_in_scan_frame"]


def steps_in_scan_frame(
    horizon: np.ndarray, horizon_occupied: np.ndarray, motion: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(probability, occupied, covered)``, each ``(K, H, W)``: the maps ``1..K`` ahead
    (``horizon`` and the decided ``horizon_occupied``, as a :class:`Prediction` holds them),
    each in the sensor frame ``k`` steps of ``motion`` on, moved into the scan's (bilinear; a
    decided map stays decided where it moves to at least half a cell), and where each step's
    grid covers the scan's. Unmoved where ``motion`` is ``None`` or zero."""
    probability = np.asarray(horizon, np.float64)
    occupied = np.asarray(horizon_occupied, bool)
    if motion is None or not np.any(np.asarray(motion)):
        return probability, occupied, np.ones(probability.shape, bool)
    h, w = probability.shape[-2:]
    moved = np.empty((len(probability), 3, h, w))
    for k in range(1, len(probability) + 1):
        # where each cell of the scan's frame lies in the frame k steps ahead
        reads = Sampler(*rigid_positions(composed_motion(motion, k), h, w, inverse=True))
        step = [probability[k - 1], occupied[k - 1], np.ones((h, w))]
        moved[k - 1] = reads(np.stack(step).astype(np.float64))
    return moved[:, 0], moved[:, 1] >= 0.5, moved[:, 2] > 0.5


def planner_grid(prediction: Prediction) -> np.ndarray:
    """``(H, W)`` int8 in the map's layout (design notes §2; lay it out with
    :func:`lidarflow.outputs.grids.laid_out`): per cell the largest probability over the
    horizon's steps that cover it, x 100 (0..100), -1 unknown (see the module).

    >>> from types import SimpleNamespace
    >>> p = SimpleNamespace(horizon=np.array([[[0.2, 0.0]], [[0.7, 0.1]]]), ahead_motion=None,
    ...     horizon_occupied=np.array([[[False, False]], [[True, False]]]),
    ...     visibility=np.array([[False, False]]))
    >>> planner_grid(p).tolist()  # seen nowhere: unknown but where a step decides occupied
    [[70, -1]]
    """
    probability, occupied, covered = steps_in_scan_frame(
        prediction.horizon, prediction.horizon_occupied, prediction.ahead_motion
    )
    largest = np.where(covered, probability, 0.0).max(axis=0)
    unseen = ~np.asarray(prediction.visibility, bool)
    unknown = (unseen & ~(occupied & covered).any(axis=0)) | ~covered.any(axis=0)
    return grid_values(largest, unknown)
