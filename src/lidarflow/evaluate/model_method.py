"""A trained model as an evaluation method: streamed through the one per-frame pipeline
(:class:`lidarflow.predict.engine.Engine`, the Predictor's), state carried across a recording."""

from __future__ import annotations

from typing import Any

import numpy as np

from lidarflow.baselines import NOTHING_MORE, FrameInputs, Takes
from lidarflow.errors import EvaluateError
from lidarflow.online.combination import Combination
from lidarflow.predict.backends import TorchBackend
from lidarflow.predict.decision import DecisionPolicy, OnlineDecisionConfig
from lidarflow.predict.engine import Backend, Engine, Frame, Step
from lidarflow.predict.headstep import HeadStepBackend
from lidarflow.predict.learning import HeadLearning, LearningConfig
from lidarflow.predict.moving import MOVING_THRESHOLD, moving_mask
from lidarflow.scan import takes_subcell

__all__ = ["ModelMethod"]


class ModelMethod:
    """A model (run by PyTorch on ``device``, or any :class:`~lidarflow.predict.engine.Backend`)
    as a :class:`~lidarflow.baselines.Method`. After each update a flow model exposes
    ``backward_flow``, ``forward_flow`` ``(2, H, W)`` (cells) and ``moving`` ``(H, W)`` bool
    (at ``moving_threshold`` cells), ``None`` for other models; :attr:`last` is the engine's
    last step. ``oracle=True`` takes the true ``next_motion``; ``res``: metres per cell.
    ``decision`` is the policy the model ships with (by default its own); ``online``
    re-decides with the offsets that did best so far: ``None`` as the policy says,
    ``True`` / ``False`` always / never, a config always with it (default ``online_config``).
    With ``learning`` the head learns on the stream (:mod:`lidarflow.predict.learning`; a
    head-only model run in NumPy), from its shipped weights again at every recording. With
    ``combined_ahead`` ``K`` above 1 and a policy that lays tracked objects (the bundled
    model's), the online combination decides its frames ``2 .. K`` ahead (:meth:`ahead`), as
    the Predictor does by default; the first stays the model's own."""

    def __init__(
        self,
        name: str,
        model: Any,
        moving_threshold: float = MOVING_THRESHOLD,
        oracle: bool = False,
        online: bool | OnlineDecisionConfig | None = None,
        online_config: OnlineDecisionConfig | None = None,
        res: float = 0.1,
        device: str = "cpu",
        decision: dict[str, Any] | None = None,
        learning: LearningConfig | None = None,
        combined_ahead: int | None = None,
    ) -> None:
        self.name = name
        self.backend: Backend = model if hasattr(model, "run") else TorchBackend(model, device)
        self.moving_threshold = moving_threshold
        caps = self.backend.capabilities
        optional = caps.ego_motion and caps.poses_optional
        # a model that may run without poses checks odometry against the scans' returns
        self.takes = Takes(caps.ego_motion, optional, optional, takes_subcell(caps.input_channels))
        record = decision if decision is not None else self.backend.decision
        policy = DecisionPolicy.from_record(record, online_config)
        policy = policy.with_online(online, online_config)
        learner = None
        if learning is not None:
            if not isinstance(self.backend, HeadStepBackend):
                raise EvaluateError(f"{name}: only a head-only model run in NumPy learns online")
            learner = HeadLearning(self.backend, learning)
        try:
            self.engine = Engine(self.backend, res, policy, oracle=oracle, learning=learner)
        except ValueError as err:
            raise EvaluateError(f"{name}: {err}") from err
        #: The online decision, ``None`` where the model decides with a fixed offset.
        self.online = self.engine.decision
        self.oracle = self.engine.oracle
        self.last: Step | None = None
        self._occupancy: np.ndarray | None = None
        self._moving: np.ndarray | None = None
        #: The online combination deciding frames 2.. ahead (``None``: the model's roll-out).
        self.combination: Combination | None = None
        if combined_ahead is not None and combined_ahead > 1 and policy.tracks:
            self.combination = Combination(combined_ahead, first=2)
        self._ahead: np.ndarray | None = None

    @property
    def backward_flow(self) -> np.ndarray | None:
        return None if self.last is None or self.last.flow is None else self.last.flow[:2]

    @property
    def forward_flow(self) -> np.ndarray | None:
        return None if self.last is None or self.last.flow is None else self.last.flow[2:]

    @property
    def motion(self) -> np.ndarray | None:
        """The motion the last frame was compensated by (cells, radians), ``None`` if none."""
        return None if self.last is None else self.last.motion

    @property
    def moving(self) -> np.ndarray | None:
        """The moving cells of the last frame given, computed on first access per frame."""
        if self._moving is None and self.forward_flow is not None:
            self._moving = moving_mask(self._occupancy, self.forward_flow, self.moving_threshold)
        return self._moving

    def reset(self) -> None:
        """A new recording: a zero state, and the head as shipped where it learns."""
        self.engine.reset()
        if self.engine.learning is not None:
            self.engine.learning.reset()
        self.last = self._occupancy = self._moving = self._ahead = None
        if self.combination is not None:
            self.combination.reset()

    def ahead(self, horizon: int) -> np.ndarray:
        """``(horizon, H, W)``: the decided maps ``1 .. horizon`` frames after the last one
        given: the model's roll-out, from frame 2 the combination's where it combines."""
        if self.last is None:
            raise RuntimeError("ahead() before any update()")
        if self._ahead is None:
            return np.stack(self.engine.roll(self.last, horizon).decided)
        if horizon > len(self._ahead):
            raise ValueError(f"{self.name} combined {len(self._ahead)} ahead, asked {horizon}")
        return self._ahead[:horizon]

    def update(
        self, occupancy: np.ndarray, visibility: np.ndarray, given: FrameInputs = NOTHING_MORE
    ) -> np.ndarray:
        """One frame, and what it is ``given`` beside its maps; the decided probability."""
        if self.takes.subcell and given.subcell is None:
            raise EvaluateError(
                f"{self.name} needs where the returns lie inside their cells (subcell_input): "
                "evaluate it on a recording, not on maps alone"
            )
        frame = Frame(
            occupancy,
            visibility,
            subcell=given.subcell,
            returns=given.returns,
            motion=given.motion,
            source="pose" if given.from_pose else "scans",
            pace=given.pace,
            next_motion=given.next_motion,
        )
        self.last = self.engine.step(frame)
        self._occupancy, self._moving = occupancy, None
        if self.combination is not None:
            assert self.engine.tracker is not None  # the policy lays tracked objects
            rollout = self.engine.roll(self.last, self.combination.horizon)
            combined = self.combination.step(
                self.engine.tracker, self.last, rollout, occupancy, visibility
            )
            self._ahead = self.combination.joined(rollout.decided, combined.decided)
        return self.last.decided
