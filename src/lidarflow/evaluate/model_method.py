"""A trained model as an evaluation method (streaming, state carried across a recording)."""

from __future__ import annotations

import numpy as np

from lidarflow.errors import EvaluateError
from lidarflow.models.streaming import StreamingModel
from lidarflow.motion.odometry import OdometryCheck
from lidarflow.motion.pacing import paced_motion
from lidarflow.motion.scanmatch import ScanOdometry, checked_motion
from lidarflow.predict.decision import (
    OnlineDecisionConfig,
    decision_for,
    decision_of,
    moved_last_map,
)
from lidarflow.scan import takes_subcell
from lidarflow.segmentation import MOVING_THRESHOLD, moving_mask

__all__ = ["ModelMethod"]


class ModelMethod:
    """Adapts :class:`StreamingModel` to the :class:`~lidarflow.predict.baselines.Method`
    protocol. After each update a flow model exposes ``backward_flow`` and ``forward_flow``
    ``(2, H, W)`` (cells) and ``moving`` ``(H, W)`` bool, the occupied cells of the frame just
    given that move on their own (:func:`lidarflow.segmentation.moving_mask` of the forward
    flow at ``moving_threshold`` cells); all three are ``None`` for other models.

    Ego-motion models (``uses_motion``) take the frame's ``motion`` (cells, this frame in the
    previous one, see :mod:`lidarflow.motion.odometry`) in ``update``; ``oracle=True`` also takes
    the true ``next_motion`` instead of the causal constant-velocity guess (an upper bound that
    needs the future pose, for evaluation only).

    ``online`` re-decides an occupancy-head model's probability with the decision offsets that
    have done best on the recording so far (:mod:`lidarflow.predict.decision`): ``None`` does so
    where the model asks for it (``online_decision`` in its kwargs), ``True`` / ``False`` always
    / never, with ``online_config`` (default: :class:`OnlineDecisionConfig`'s); a config always,
    with that configuration.

    A model that may run without poses (``poses_optional``) checks the odometry against the
    scans and, where they disagree, takes the scans' own motion
    (:func:`lidarflow.motion.scanmatch.checked_motion`, as the Predictor does): refined on the
    scans' returns when ``update`` is given them, which needs ``res``, the grid's cell size in
    metres."""

    def __init__(
        self,
        name: str,
        stream: StreamingModel,
        moving_threshold: float = MOVING_THRESHOLD,
        oracle: bool = False,
        online: bool | OnlineDecisionConfig | None = None,
        online_config: OnlineDecisionConfig | None = None,
        res: float = 0.1,
    ) -> None:
        self.name = name
        self.stream = stream
        self.moving_threshold = moving_threshold
        self.uses_motion = bool(getattr(stream.model, "ego_motion", False))
        self.poses_optional = bool(getattr(stream.model, "poses_optional", False))
        # A model that may run without poses stops using the odometry while it disagrees with
        # the scans (e.g. a base's odometry read as a scanner's turned on the base), and takes
        # the scans' own motion instead, as the Predictor does.
        self.odometry = OdometryCheck() if self.poses_optional else None
        self.scans = ScanOdometry(res) if self.poses_optional else None
        self.takes_returns = self.poses_optional
        self.takes_subcell = takes_subcell(stream.model.input_channels)
        self.oracle = oracle and self.uses_motion
        try:
            self.online = decision_for(decision_of(stream.model), online, online_config)
        except ValueError as err:
            raise EvaluateError(str(err)) from err
        self.backward_flow: np.ndarray | None = None
        self.forward_flow: np.ndarray | None = None
        #: The motion the last frame was compensated by (cells, radians), ``None`` if none.
        self.motion: np.ndarray | None = None
        self._occupancy: np.ndarray | None = None
        self._moving: np.ndarray | None = None

    @property
    def moving(self) -> np.ndarray | None:
        """The moving cells of the last frame given, computed on first access per frame."""
        if self._moving is None and self.forward_flow is not None:
            self._moving = moving_mask(self._occupancy, self.forward_flow, self.moving_threshold)
        return self._moving

    def reset(self) -> None:
        self.stream.reset()
        self.backward_flow = self.forward_flow = self._occupancy = self._moving = None
        self.motion = None
        if self.odometry is not None:
            self.odometry.reset()
        if self.scans is not None:
            self.scans.reset()
        if self.online is not None:
            self.online.reset()

    def update(
        self,
        occupancy: np.ndarray,
        visibility: np.ndarray,
        motion: np.ndarray | None = None,
        next_motion: np.ndarray | None = None,
        returns: np.ndarray | None = None,
        from_pose: bool = True,
        subcell: np.ndarray | None = None,
        pace: float | None = None,
    ) -> np.ndarray:
        """One frame; ``returns``: its scan's returns (:func:`~lidarflow.motion.icp.
        scan_points`) where known; ``from_pose``: ``motion`` came from poses (else from the
        scans, and is only checked); ``subcell``: where its returns lie inside their cells
        ``(2, H, W)``, which a model with ``takes_subcell`` needs; ``pace``: after a long step in
        time, the typical step over this one (the guess of the next motion is scaled by it,
        :func:`lidarflow.motion.pacing.paced_motion`)."""
        if self.takes_subcell and subcell is None:
            raise EvaluateError(
                f"{self.name} needs where the returns lie inside their cells (subcell_input): "
                "evaluate it on a recording, not on maps alone"
            )
        if self.odometry is not None:
            motion, trusted = checked_motion(
                self.odometry, self.scans, occupancy, motion, from_pose, returns, pace
            )
            next_motion = next_motion if trusted else None
        self.motion = motion
        guess = next_motion if self.oracle else paced_motion(motion, pace)
        result = self.stream.step(occupancy, visibility, motion, guess, subcell)
        self._occupancy, self._moving = occupancy, None
        if result.flow is None:
            self.backward_flow = self.forward_flow = None
        else:
            self.backward_flow, self.forward_flow = result.flow[:2], result.flow[2:]
        if self.online is None:
            return result.probability
        return self.online.update(
            result.probability, occupancy, visibility, moved_last_map(occupancy, self.backward_flow)
        )
