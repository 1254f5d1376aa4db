"""The mover-weighted cross-entropy (``loss.mover_weight``, the ``head_movers`` recipe).

The movers are ~1 % of the occupied cells, so the plain cross-entropy of the next map is
dominated by walls and free space, and a head that erases the transients loses almost nothing
by it. With ``loss.mover_weight`` ``w != 1`` the cells of each training recording's dynamic
region (the region the mover metric scores in, :func:`lidarflow.evaluate.dynamic.recording_region`,
found in hindsight on that training recording: world frame where it has poses, the simulator's
true moving cells where it has them) weigh ``w`` times the others.

The loop stays one loop: the training windows carry their region ``(T, H, W)`` (frame ``t``'s
region in frame ``t``'s own cells, so in the frame its target map is in) as their last item
(:func:`recording_regions`, :class:`~lidarflow.train.data.Windows`), :func:`take_region`
lifts it off each batch before the batch is split as usual, and the loss weighs the target
frame's region (:func:`lidarflow.losses.deeptracking_loss`). Validation windows carry none:
the validation loss stays the plain one.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from torch import Tensor

from lidarflow.data.recording import Recording
from lidarflow.evaluate.dynamic import recording_region
from lidarflow.evaluate.stream import ground_truth_moving
from lidarflow.scan import GridSpec
from lidarflow.train.config import TrainConfig

__all__ = ["mover_weighted", "recording_regions", "take_region"]


def mover_weighted(config: TrainConfig) -> bool:
    """Whether the run weighs the dynamic region's cells (``loss.mover_weight != 1``)."""
    return config.loss.mover_weight != 1.0


def recording_regions(
    recordings: Sequence[Recording], maps: Sequence[np.ndarray], grid: GridSpec
) -> list[np.ndarray]:
    """Per recording, its dynamic region of every frame, bool ``(N, H, W)``, from its maps
    ``(N, C >= 2, H, W)`` (channels occupancy, visibility) on ``grid``, as `evaluate` finds it."""
    regions = []
    for recording, m in zip(recordings, maps, strict=True):
        region = recording_region(
            recording, grid, m[:, 0], m[:, 1], ground_truth_moving(recording, grid)
        )
        regions.append(np.stack([region(t) for t in range(len(m))]).astype(bool))
    return regions


def take_region(batch: Sequence[Tensor]) -> tuple[Tensor | list[Tensor], Tensor]:
    """``[*rest, region]`` -> (``rest`` alone or as a list, region): the batch as it is without
    regions, and the windows' regions ``(B, T, H, W)``."""
    *rest, region = batch
    return (rest if len(rest) > 1 else rest[0]), region
