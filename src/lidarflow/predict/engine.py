"""The per-frame pipeline, written once: motion, model step, decision, roll-out.

Every user of a trained model streams it through :class:`Engine`: the robot's
:class:`~lidarflow.predict.Predictor`, ``evaluate``'s model method and the horizon scorer
(:mod:`lidarflow.evaluate`). One :meth:`Engine.step` per frame, in order:

1. **Motion** (ego-motion models only): the sensor's motion since the previous frame, in cells
   and radians (:mod:`lidarflow.motion`). Where it comes from is the frame's ``source``:
   ``"pose"`` (odometry; ``None`` where unknown), ``"scans"`` (matched from the scans by the
   caller, ``None`` where no match counted) or ``"none"`` (nothing given: a model that may run
   without poses matches the scans here). A model that may run without poses checks the motion
   against the scans (:func:`lidarflow.motion.scanmatch.checked_motion`) and compensates by the
   scans' own where odometry disagrees. The guess of the motion to the next frame is the last
   one again, scaled to one typical step after a long step in time
   (:func:`lidarflow.motion.pacing.paced_motion`).
2. **Model step** on the backend (PyTorch or ONNX Runtime, :mod:`lidarflow.predict.backends`),
   its recurrent state carried from frame to frame.
3. **Decision** (:mod:`lidarflow.predict.decision`): an occupancy-head model's calibrated
   probability is decided with the policy's offset, or online with the offsets that have done
   best on this stream so far. With the policy's ``tracks`` a tracker runs beside the model on
   the same frames and motion (:class:`lidarflow.tracking.Tracker`), and the objects it
   follows join the decided map where their velocity takes them.
4. **Roll-out** (:meth:`Engine.roll`, on request): the decided prediction fed back as the next
   input, ``k`` steps ahead, on a copy of the state (the fed-back maps must not leak into the
   state the next real frame continues from), each step assuming one more typical step of the
   same motion and re-decided with the current choice. The tracked objects join each step
   where ``k`` steps of their velocity take them, and are not fed back: the model rolls out as
   it would alone, so that what the tracker adds at one step does not linger in the next.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from lidarflow.geometry import FlowWarp
from lidarflow.motion.odometry import OdometryCheck
from lidarflow.motion.pacing import paced_motion
from lidarflow.motion.scanmatch import ScanOdometry, checked_motion
from lidarflow.predict.decision import DecisionPolicy
from lidarflow.predict.learning import HeadLearning
from lidarflow.predict.logits import decided_probability
from lidarflow.predict.offsets import moved_last_map
from lidarflow.predict.step import Backend, StepInputs
from lidarflow.scan import takes_subcell
from lidarflow.tracking import Tracker, Tracks

__all__ = ["Backend", "Engine", "Frame", "MotionSource", "Rollout", "Step"]

#: Frames a carried map keeps the tracker's held cells (occupied cells that are not background
#: yet no track took, mostly a person beside a wall; :class:`~lidarflow.tracking.Tracks`): one,
#: where the head alone would let them fade (docs/research/carry_movers/).
HELD_FRAMES = 1

#: Where a frame's motion came from (see the module's docstring).
MotionSource = Literal["pose", "scans", "none"]


@dataclass(frozen=True)
class Frame:
    """One frame's input: its maps ``(H, W)``; ``subcell`` ``(2, H, W)`` (where its returns lie
    inside their cells, for models that take it; zeros when ``None``); ``returns`` ``(N, 2)``
    (its scan's returns in metres, :func:`lidarflow.motion.icp.scan_points`, which refine scan
    matching); ``motion`` and its ``source`` (see the module's docstring); ``pace`` (after a
    long step in time: the typical step over this one); ``next_motion``: the true motion to the
    next frame, used only by an engine built with ``oracle``."""

    occupancy: np.ndarray
    visibility: np.ndarray
    subcell: np.ndarray | None = None
    returns: np.ndarray | None = None
    motion: np.ndarray | None = None
    source: MotionSource = "pose"
    pace: float | None = None
    next_motion: np.ndarray | None = None


@dataclass(frozen=True)
class Rollout:
    """The probabilities ``1 .. K`` frames ahead ``(K, H, W)``, as :class:`Step` has them, and
    ``model_only``, the model's own decided maps without the tracked objects."""

    probability: np.ndarray
    decided: np.ndarray
    model_only: np.ndarray


@dataclass(frozen=True)
class Step:
    """What one :meth:`Engine.step` made: ``probability`` ``(H, W)``, the model's (calibrated,
    for an occupancy head) probability of the next map, and ``decided``, the probability its
    decision policy thresholds at 0.4 (the same for a model without a head); ``flow``
    ``(4, H, W)`` in cells (``B_col, B_row, F_col, F_row``; ``None`` for models without flow);
    ``motion`` the motion the step was compensated by (``None``: not compensated). The rest is
    what :meth:`Engine.roll` continues from (``tracks``: the tracked objects, where the policy
    carries them, and ``model_only``: the model's own decided map, without them)."""

    probability: np.ndarray
    decided: np.ndarray
    flow: np.ndarray | None
    motion: np.ndarray | None
    maps: np.ndarray
    state: Any
    ahead: np.ndarray | None
    tracks: Tracks | None = None
    model_only: np.ndarray | None = None


class Engine:
    """A model streamed one frame at a time (see the module's docstring).

    Args:
        backend: runs the model's step.
        res: the grid's cell size in metres (scan matching on returns needs it).
        policy: how an occupancy head's next map is decided (default: at 0.4 as it is); a
            ``ValueError`` for a model without one, unless it is the default.
        check_odometry: a model that may run without poses checks odometry against the scans.
        scan_odometry: such a model takes the motion from the scans where odometry is missing
            or disagrees (off: those steps run uncompensated).
        oracle: an ego-motion model takes the frame's true ``next_motion`` instead of the
            causal guess (an upper bound that needs the future; evaluation only).
        learning: the head learns on the stream (:mod:`lidarflow.predict.learning`): each
            frame's occupancy is the label of the step before it, unless the frame comes after
            a long step in time (``pace``: its label would be of another moment).
    """

    def __init__(
        self,
        backend: Backend,
        res: float = 0.1,
        policy: DecisionPolicy | None = None,
        check_odometry: bool = True,
        scan_odometry: bool = True,
        oracle: bool = False,
        learning: HeadLearning | None = None,
    ) -> None:
        self.backend = backend
        if learning is not None and learning.backend is not backend:
            raise ValueError("the head that learns must be the backend the engine runs")
        self.learning = learning
        self._trace: Any = None  # the last real frame's step, for its label
        caps = self.capabilities = backend.capabilities
        self.policy = policy or DecisionPolicy()
        if self.policy != DecisionPolicy() and not caps.occupancy_head:
            raise ValueError(
                "a decision offset or online decision needs a model with an occupancy head"
            )
        #: The online decision (None where the policy has none), for a look inside.
        self.decision = self.policy.decision(backend.gain)
        self.oracle = oracle and caps.ego_motion
        optional = caps.ego_motion and caps.poses_optional
        #: The odometry check (None where the model does not check it), for a look inside.
        self.odometry = OdometryCheck() if optional and check_odometry else None
        self._scans = ScanOdometry(res) if optional and scan_odometry else None
        #: The tracker whose objects join the decided map (None where the policy has none).
        self.tracker = Tracker(res=res) if self.policy.tracks else None
        self._state: Any = None
        self._warp = FlowWarp()  # the online decision's moved map; a roll-out's flow repeats

    @property
    def wants_returns(self) -> bool:
        """Whether a frame's ``returns`` are used (to match or check the motion)."""
        return self._scans is not None

    def reset(self) -> None:
        """Forget the past: the next step starts a new stream from a zero state."""
        self._state = self._trace = None
        for part in (self.odometry, self._scans, self.decision, self.tracker):
            if part is not None:
                part.reset()

    def _motion(self, frame: Frame) -> tuple[np.ndarray | None, bool]:
        """The motion this frame is compensated by, and whether the odometry check trusts
        the motion given."""
        if not self.capabilities.ego_motion:
            return None, False
        motion, scans = frame.motion, self._scans
        if frame.source == "none" and scans is not None:
            motion = scans.update(frame.occupancy, frame.returns)
        from_pose = frame.source == "pose"
        if self.odometry is not None:
            return checked_motion(
                self.odometry, scans, frame.occupancy, motion, from_pose, frame.returns, frame.pace
            )
        if from_pose and scans is not None:
            scans.observe(frame.occupancy, frame.returns)
        return motion, True

    def _maps(self, occupancy: Any, visibility: Any, subcell: np.ndarray | None) -> np.ndarray:
        """``(1, C, H, W)`` float32: the model's input for one frame."""
        maps = np.stack([occupancy, visibility]).astype(np.float32)
        if takes_subcell(self.capabilities.input_channels):
            extra = np.zeros((2, *maps.shape[1:])) if subcell is None else subcell
            maps = np.concatenate([maps, np.asarray(extra, np.float32)])
        return maps[None]

    def step(self, frame: Frame) -> Step:
        """Feed one frame and predict the next."""
        maps = self._maps(frame.occupancy, frame.visibility, frame.subcell)
        if self._state is None:
            self._state = self.backend.init_state(*maps.shape[-2:])
        motion, trusted = self._motion(frame)
        if self.oracle:
            guess = frame.next_motion if trusted else None
        else:
            guess = paced_motion(motion, frame.pace)  # None: the last motion again
        if self.learning is not None and self._trace is not None and frame.pace is None:
            self.learning.learn(self._trace, frame.occupancy)
        probability, out, self._state = self.backend.run(
            StepInputs(maps, motion, guess), self._state
        )
        if self.learning is not None:
            self._trace = self.learning.backend.trace
        flow = out[0, :4] if self.capabilities.flow else None
        own = probability[0, 0]
        decided = self._decide(own, frame.occupancy, self._backward(out), frame.visibility)
        tracks, model_only = None, decided
        if self.tracker is not None:
            self.tracker.observe(frame.occupancy, frame.visibility, motion, frame.pace)
            tracks = self.tracker.tracks(HELD_FRAMES)
            decided = np.maximum(decided, tracks.at(1))
        # Each step of a roll-out is one typical step of the same motion.
        ahead = motion if guess is None else guess
        return Step(own, decided, flow, motion, maps, self._state, ahead, tracks, model_only)

    def _backward(self, out: np.ndarray) -> np.ndarray | None:
        """The step's backward flow ``(2, H, W)``, which moves the last map for the online
        decision: also that of a model without a flow network (``capabilities.flow`` false),
        whose flow channels hold the platform's own motion (zero without ego motion)."""
        return out[0, :2] if self.capabilities.out_channels >= 4 else None

    def _decide(
        self,
        probability: np.ndarray,
        last: np.ndarray,
        backward: np.ndarray | None,
        visibility: np.ndarray | None = None,
    ) -> np.ndarray:
        """The probability the policy thresholds (``last``: the map the prediction was made
        from, ``backward``: the step's backward flow): with an online decision, updated on this
        frame (``visibility`` given) or applied with its current choice (a roll-out's step)."""
        if self.decision is None:
            return decided_probability(probability, self.policy.offset)
        moved = moved_last_map(last, backward, self._warp)
        if visibility is None:
            return self.decision.apply(probability, last, moved)
        return self.decision.update(probability, last, visibility, moved)

    def roll(self, step: Step, horizon: int) -> Rollout:
        """The predictions ``1 .. horizon`` frames ahead of ``step`` (the first is the step's
        own): each decided prediction fed back with the frame's visibility (and no returns: zero
        sub-cell maps), on a copy of the state, and decided with the current choice."""
        probabilities, decided = [step.probability], [step.decided]
        # what is fed back: the model's own map, without the tracked objects
        model_only = step.decided if step.model_only is None else step.model_only
        own, tracks, state = [model_only], step.tracks, step.state
        for k in range(2, horizon + 1):
            fed = np.zeros_like(step.maps)
            fed[0, 0], fed[0, 1] = model_only, step.maps[0, 1]
            probability, out, state = self.backend.run(StepInputs(fed, step.ahead), state)
            probabilities.append(probability[0, 0])
            model_only = self._decide(probability[0, 0], model_only, self._backward(out))
            own.append(model_only)
            decided.append(model_only if tracks is None else np.maximum(model_only, tracks.at(k)))
        return Rollout(np.stack(probabilities), np.stack(decided), np.stack(own))
