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
3. **Decision**: a model with an online decision (:mod:`lidarflow.predict.decision`) re-decides
   its next map with the offsets that have done best on this stream so far.
4. **Roll-out** (:meth:`Engine.roll`, on request): the prediction fed back as the next input,
   ``k`` steps ahead, on a copy of the state (the fed-back maps must not leak into the state the
   next real frame continues from), each step assuming one more typical step of the same motion
   and re-decided with the current choice.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal, Protocol

import numpy as np

from lidarflow.motion.odometry import OdometryCheck
from lidarflow.motion.pacing import paced_motion
from lidarflow.motion.scanmatch import ScanOdometry, checked_motion
from lidarflow.predict.decision import OnlineDecision
from lidarflow.predict.offsets import moved_last_map

__all__ = ["Backend", "Engine", "Frame", "MotionSource", "Step"]

#: Where a frame's motion came from (see the module's docstring).
MotionSource = Literal["pose", "scans", "none"]


class Backend(Protocol):
    """One model step on NumPy arrays (:class:`~lidarflow.predict.backends.TorchBackend`,
    :class:`~lidarflow.predict.backends.OnnxBackend`)."""

    uses_motion: bool
    poses_optional: bool
    input_channels: int
    out_channels: int

    def init_state(self, height: int, width: int) -> Any: ...

    def run(
        self,
        maps: np.ndarray,
        state: Any,
        motion: np.ndarray | None = None,
        next_motion: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray, Any]: ...


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
class Step:
    """What one :meth:`Engine.step` made: ``probability`` ``(H, W)``, the next map's (decided
    online where the model has an online decision), ``model_probability`` the model's own,
    ``flow`` ``(4, H, W)`` in cells (``B_col, B_row, F_col, F_row``; ``None`` for models
    without flow), ``motion`` the motion the step was compensated by (``None``: not
    compensated). The rest is what :meth:`Engine.roll` continues from."""

    probability: np.ndarray
    model_probability: np.ndarray
    flow: np.ndarray | None
    motion: np.ndarray | None
    maps: np.ndarray
    state: Any
    ahead: np.ndarray | None


class Engine:
    """A model streamed one frame at a time (see the module's docstring).

    Args:
        backend: runs the model's step.
        res: the grid's cell size in metres (scan matching on returns needs it).
        decision: the online decision, if the model is to be re-decided on the stream.
        check_odometry: a model that may run without poses checks odometry against the scans.
        scan_odometry: such a model takes the motion from the scans where odometry is missing
            or disagrees (off: those steps run uncompensated).
        oracle: an ego-motion model takes the frame's true ``next_motion`` instead of the
            causal guess (an upper bound that needs the future; evaluation only).
    """

    def __init__(
        self,
        backend: Backend,
        res: float = 0.1,
        decision: OnlineDecision | None = None,
        check_odometry: bool = True,
        scan_odometry: bool = True,
        oracle: bool = False,
    ) -> None:
        self.backend = backend
        self.decision = decision
        self.oracle = oracle and backend.uses_motion
        optional = backend.uses_motion and backend.poses_optional
        #: The odometry check (None where the model does not check it), for a look inside.
        self.odometry = OdometryCheck() if optional and check_odometry else None
        self._scans = ScanOdometry(res) if optional and scan_odometry else None
        self._state: Any = None

    @property
    def wants_returns(self) -> bool:
        """Whether a frame's ``returns`` are used (to match or check the motion)."""
        return self._scans is not None

    @property
    def has_flow(self) -> bool:
        return self.backend.out_channels >= 4

    def reset(self) -> None:
        """Forget the past: the next step starts a new stream from a zero state."""
        self._state = None
        for part in (self.odometry, self._scans, self.decision):
            if part is not None:
                part.reset()

    def _motion(self, frame: Frame) -> tuple[np.ndarray | None, bool]:
        """The motion this frame is compensated by, and whether the odometry check trusts
        the motion given."""
        if not self.backend.uses_motion:
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
        if self.backend.input_channels > 2:
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
        probability, out, self._state = self.backend.run(maps, self._state, motion, guess)
        flow = out[0, :4] if self.has_flow else None
        own = probability[0, 0]
        decided = own
        if self.decision is not None:
            moved = moved_last_map(frame.occupancy, None if flow is None else flow[:2])
            decided = self.decision.update(own, frame.occupancy, frame.visibility, moved)
        # Each step of a roll-out is one typical step of the same motion.
        ahead = motion if guess is None else guess
        return Step(decided, own, flow, motion, maps, self._state, ahead)

    def roll(self, step: Step, horizon: int) -> list[np.ndarray]:
        """The probabilities ``1 .. horizon`` frames ahead of ``step`` (the first is
        ``step.probability``): each prediction fed back with the frame's visibility (and no
        returns: zero sub-cell maps), on a copy of the state."""
        future = [step.probability]
        state = step.state
        for _ in range(horizon - 1):
            fed = np.zeros_like(step.maps)
            fed[0, 0], fed[0, 1] = future[-1], step.maps[0, 1]
            probability, out, state = self.backend.run(fed, state, step.ahead)
            if self.decision is not None:
                flow = out[0, :2] if self.has_flow else None
                moved = moved_last_map(future[-1], flow)
                future.append(self.decision.apply(probability[0, 0], future[-1], moved))
            else:
                future.append(probability[0, 0])
        return future
