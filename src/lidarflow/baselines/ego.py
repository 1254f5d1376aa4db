"""The baseline that only compensates the platform's own motion: the last map moved into the
next sensor frame (:class:`CopyLastEgo`)."""

from __future__ import annotations

import numpy as np

from lidarflow.baselines.method import NOTHING_MORE, FrameInputs, Takes
from lidarflow.geometry import rigid_moved
from lidarflow.motion.pacing import paced_motion

__all__ = ["CopyLastEgo"]


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
        # after a long step the last motion spans it: the guess is scaled to one, as the models'
        guessed = paced_motion(given.motion, given.pace)
        m = given.next_motion if self.oracle else (given.motion if guessed is None else guessed)
        if m is None:
            return occupancy.astype(np.float32)
        return np.clip(rigid_moved(occupancy, m), 0.0, 1.0).astype(np.float32)
