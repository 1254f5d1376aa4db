"""The streaming predictor a robot calls once per scan.

>>> from lidarflow.predict import Predictor                     # doctest: +SKIP
>>> predictor = Predictor()            # bundled model; Predictor("run_dir") or ("m.onnx")
>>> for scan in scans:                 # lidarflow.scan.Scan (maps: models without subcell)
...     p = predictor.update(scan)         # ego-motion models: update(scan, pose=(x, y, yaw))
...     p.probability, p.occupied, p.backward_flow, p.forward_flow, p.moving

Ego motion: a model trained with ``--ego-motion`` wants the sensor pose ``(x, y, yaw)`` (metres,
radians, any fixed frame such as odometry's) with every scan. The motion since the previous
update warps the recurrent state into the current frame, and the prediction is moved into the
next frame assuming the same motion again (constant velocity: only poses up to now are known).
After a long step in the scans' stamps (more than 1.5 typical ones: a gap, or a scan or two
dropped; :mod:`lidarflow.data.gaps`) the last motion spans it, so the guess is that motion
scaled to one typical step (the state is still moved by all of it); a scan without a stamp
(``stamp_ns`` 0) is never after a long step and does not count as a step.
A model that may run without poses (``poses_optional``, the bundled one) takes the motion from
the scans where no pose is given (:class:`lidarflow.motion.scanmatch.ScanOdometry`: refined on the
returns when ``update`` is given a :class:`~lidarflow.scan.Scan`). Otherwise, without a pose
(``None`` or NaN) that step is not compensated (``Prediction.ego_compensated`` is
False), as a model without odometry would run; horizon steps beyond the first repeat the last
motion.

A model built with ``subcell_input`` also sees where each return lies inside its cell
(:func:`lidarflow.scan.subcell_batch`), which only a :class:`~lidarflow.scan.Scan` carries: give
its ``update`` scans, not maps.
"""

from __future__ import annotations

import dataclasses
import io
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from lidarflow.atomic import write_bytes
from lidarflow.errors import PredictError
from lidarflow.motion.icp import scan_points
from lidarflow.motion.odometry import metres_to_cells, relative_motions
from lidarflow.motion.pacing import StepClock
from lidarflow.online.combination import Combination
from lidarflow.online.stacking import StackingConfig
from lidarflow.predict.backends import learning_backend, load_backend, recorded_grid
from lidarflow.predict.decision import DecisionPolicy, OnlineDecision, OnlineDecisionConfig
from lidarflow.predict.engine import Engine, Frame
from lidarflow.predict.learning import HeadLearning, LearningConfig
from lidarflow.predict.moving import MOVING_THRESHOLD, moving_mask
from lidarflow.predict.offsets import THRESHOLD
from lidarflow.scan import GridSpec, Scan, rasterize, subcell_batch, takes_subcell
from lidarflow.tracking import Track

__all__ = ["Prediction", "Predictor"]

_HEAD = "head/"  # what the head learnt, in a file of save_learned


@dataclass(frozen=True)
class Prediction:
    """What one update returns.

    Attributes:
        probability: ``(H, W)`` probability that each cell is occupied in the next frame
            (calibrated, for an occupancy-head model such as the bundled one).
        occupied: ``(H, W)`` bool, the decided next map: the probability decided by the
            Predictor's :class:`~lidarflow.predict.decision.DecisionPolicy` (an offset on the
            logit, chosen online for the bundled model) at 0.4. For a model without a head it
            is ``probability >= 0.4``.
        backward_flow, forward_flow: ``(2, H, W)`` flow in cells (column, row), ``None`` for
            models that predict occupancy directly (DeepTracking) and LiDAR-FlowNet without its
            flow network (``capabilities.flow`` false).
        horizon: ``(K, H, W)`` probabilities 1..K frames ahead (``horizon[0]`` is
            ``probability``); each step ahead is fed the decided map before it.
        horizon_occupied: ``(K, H, W)`` bool, the decided maps 1..K frames ahead.
        occupancy, visibility: the maps of the frame just given.
        ego_compensated: an ego-motion model was given the motion since the previous scan (from
            the pose, or matched from the scans).
        moving_threshold: cells per frame of motion of its own above which a cell is moving.
        stamp_ns: the stamp of the scan just given (0 for maps, or a scan without one).
        step_ns: the stream's step between scans so far (the typical one once known;
            :attr:`lidarflow.motion.pacing.StepClock.step_ns`), ``None`` until two stamped
            scans came: what :meth:`stamp_ahead_ns` counts ahead by.
        tracks: the objects the tracker follows and saw in this scan, each a
            :class:`~lidarflow.tracking.Track` (position in metres in the sensor frame of this
            scan, velocity in m/s once ``step_ns`` is known, its cells); ``None`` where the
            decision policy runs no tracker (:attr:`DecisionPolicy.tracks
            <lidarflow.predict.decision.DecisionPolicy.tracks>`).
        ahead_motion: ``(3,)`` the motion each step ahead assumes (cells and radians, the pose
            of the frame ``k + 1`` in frame ``k``'s; :mod:`lidarflow.geometry`'s convention):
            the map ``k`` frames ahead lies in the sensor frame ``k`` such steps on. ``None``
            where the maps are not moved (a model without ego motion, or no motion known):
            they all lie in the frame of the scan just given.
    """

    probability: np.ndarray
    occupied: np.ndarray
    backward_flow: np.ndarray | None
    forward_flow: np.ndarray | None
    horizon: np.ndarray
    horizon_occupied: np.ndarray
    occupancy: np.ndarray
    visibility: np.ndarray
    ego_compensated: bool = False
    moving_threshold: float = MOVING_THRESHOLD
    stamp_ns: int = 0
    step_ns: int | None = None
    tracks: tuple[Track, ...] | None = None
    ahead_motion: np.ndarray | None = None

    def stamp_ahead_ns(self, k: int = 1) -> int:
        """The time the prediction ``k`` frames ahead is for: the scan's stamp plus ``k``
        steps; the scan's own stamp while no step is known yet (the first scan)."""
        return self.stamp_ns + k * (self.step_ns or 0)

    @cached_property
    def moving(self) -> np.ndarray | None:
        """``(H, W)`` bool, the occupied cells of the frame just given that move on their own
        (forward flow less the platform's motion longer than ``moving_threshold`` cells;
        :func:`lidarflow.predict.moving.moving_mask`); ``None`` for models without flow.

        Computed on first access (~0.6 ms on a 100 x 100 grid, a tenth of an update), so a
        robot that only wants the next map does not pay for it.
        """
        if self.forward_flow is None:
            return None
        return moving_mask(self.occupancy, self.forward_flow, self.moving_threshold)


class Predictor:
    """Stateful next-map predictor.

    Args:
        model: a run folder or ``.safetensors`` file (PyTorch), an ``.onnx`` file (onnxruntime,
            no PyTorch needed), or ``None`` for the bundled pretrained model (its head step in
            NumPy, read without PyTorch: :func:`~lidarflow.predict.backends.load_backend`).
        grid: the map grid (default: the one the model was trained on, as its model.json or
            the ONNX file's metadata says; else 100 x 100 at 0.1 m, the bundled model's).
        horizon: frames ahead to predict; beyond the first, predictions are fed back as input.
        threads: CPU threads for inference, process-wide (default 1: many times faster beside
            a busy process, benchmarks/results/threads.json; ``None``: leave PyTorch's setting).
        moving_threshold: cells per frame of motion of its own above which an occupied cell is
            reported moving (:data:`lidarflow.predict.moving.MOVING_THRESHOLD` by default).
        check_odometry: for a model that may run without poses (``poses_optional``, the bundled
            one): stop compensating while the poses disagree with the scans
            (:class:`~lidarflow.motion.odometry.OdometryCheck`). Off: every pose given is used.
        scan_odometry: for such a model, where no pose is given, take the motion from the scans
            (:class:`lidarflow.motion.scanmatch.ScanOdometry`: the maps matched, and refined on
            the returns where ``update`` is given a :class:`~lidarflow.scan.Scan`); off: those
            steps run uncompensated.
        decision: how the next map is decided (``Prediction.occupied``): a
            :class:`~lidarflow.predict.decision.DecisionPolicy`; ``None``: the one the model
            ships with (its ``model.json``, or the ONNX file's marks).
        online_decision: overrides whether that policy chooses its offsets online, on this
            stream's own past frames (:mod:`lidarflow.predict.decision`; a roll-out feeds back
            the decided map and re-decides every step with the same choice): ``None`` as the
            policy says, ``True`` / ``False`` on / off, a config on with it.
        combine: predict with the online combination (:mod:`lidarflow.online`): the model,
            its tracked objects, the tracker, the ego-moved last map and the temporal average
            weighed per horizon ``1 .. horizon`` by the scans that arrive (a
            :class:`~lidarflow.online.stacking.StackingConfig` to configure it). Then
            ``Prediction.probability`` and ``horizon`` are the combination's. ``None`` (the
            default): the combination decides the frames ``2 .. horizon`` and the model the
            first, for a model whose policy lays tracked objects over its map (the bundled
            one) and a horizon above 1; otherwise off. ``False``: off.
        learn: the model's head keeps learning on the stream, each scan the label of the
            prediction made for it (:mod:`lidarflow.predict.learning`; a
            :class:`~lidarflow.predict.learning.LearningConfig` to configure it). Needs a
            head-only model such as the bundled one, run in NumPy on the CPU.

    What the combination and the head learnt can be saved and loaded (:meth:`save_learned`,
    :meth:`load_learned`); :meth:`reset` forgets it.
    """

    def __init__(
        self,
        model: str | Path | None = None,
        grid: GridSpec | None = None,
        horizon: int = 1,
        threads: int | None = 1,
        device: str = "cpu",
        moving_threshold: float = MOVING_THRESHOLD,
        check_odometry: bool = True,
        scan_odometry: bool = True,
        online_decision: bool | OnlineDecisionConfig | None = None,
        decision: DecisionPolicy | None = None,
        combine: bool | StackingConfig | None = None,
        learn: bool | LearningConfig = False,
    ) -> None:
        if horizon < 1:
            raise PredictError(f"horizon must be >= 1, got {horizon}")
        if not moving_threshold >= 0:
            raise PredictError(f"moving_threshold must be >= 0 cells, got {moving_threshold}")
        self.moving_threshold = moving_threshold
        self.horizon = horizon
        self.backend: Any
        self.backend, self.card = load_backend(model, threads, device)
        recorded = recorded_grid(self.card)
        # The grid the model was trained (or exported) for, unless told otherwise.
        self.grid = grid or recorded or GridSpec()
        self._pose: np.ndarray | None = None
        # Scans' stamps: after a long step the last motion spans it, and the guess of the next
        # one is scaled to a typical step (lidarflow.motion.pacing, as evaluate does).
        self._clock = StepClock()
        if decision is None:  # the policy the model ships with
            decision = DecisionPolicy.from_record(self.card.get("decision"))
        #: How the next map is decided (``Prediction.occupied``).
        self.decision = decision.with_online(online_decision)
        #: The online combination (``None`` without ``combine``), for a look inside.
        self.combination: Combination | None = None
        first = 1  # the first frame ahead the combination decides
        if combine is None:  # measured: docs/research/online_combination ("sixteen robots")
            combine, first = horizon > 1 and self.decision.tracks, 2
        if combine is not False:
            config = combine if isinstance(combine, StackingConfig) else None
            self.combination = Combination(horizon, config, first)
            self.decision = dataclasses.replace(self.decision, tracks=True)  # an expert
        #: The head learning on the stream (``None`` without ``learn``), for a look inside.
        self.learning: HeadLearning | None = None
        if learn is not False:
            self.backend = learning_backend(self.backend)
            config = learn if isinstance(learn, LearningConfig) else None
            self.learning = HeadLearning(self.backend, config)
        try:
            self.engine = Engine(
                self.backend,
                self.grid.res,
                self.decision,
                check_odometry,
                scan_odometry,
                learning=self.learning,
            )
        except ValueError as err:
            raise PredictError(
                f"{err} (an ONNX file exported before lidarflow marked the decision in it: "
                "export it again)"
            ) from err

    @property
    def online(self) -> OnlineDecision | None:
        """The online decision choosing the offsets on this stream, ``None`` where the policy
        decides with a fixed offset."""
        return self.engine.decision

    @property
    def uses_motion(self) -> bool:
        """Whether the model compensates ego motion (then give ``update`` the sensor pose)."""
        return self.backend.capabilities.ego_motion

    @property
    def poses_optional(self) -> bool:
        """Whether an ego-motion model may run without poses (without one it takes the motion
        from the scans, ``scan_odometry``, else runs uncompensated)."""
        return self.backend.capabilities.poses_optional

    def reset(self) -> None:
        """Forget the past and what was learnt on it: the next update starts from a zero state,
        the model as shipped."""
        self._pose = None
        self._clock.reset()
        self.engine.reset()
        for learnt in (self.combination, self.learning):
            if learnt is not None:
                learnt.reset()

    def save_learned(self, path: str | Path) -> Path:
        """Write what the online combination and the head learnt on this stream to ``path``
        (``.npz``, replaced whole): :meth:`load_learned` continues from it, on this robot
        later."""
        if self.combination is None and self.learning is None:
            raise PredictError("nothing learnt to save: this Predictor neither combines nor learns")
        state = {} if self.combination is None else self.combination.state()
        if self.learning is not None:
            state.update({_HEAD + k: v for k, v in self.learning.state().items()})
        buffer = io.BytesIO()
        np.savez(buffer, **state)
        return write_bytes(path, buffer.getvalue())

    def load_learned(self, path: str | Path) -> None:
        """Continue the online combination and the head from what :meth:`save_learned`
        wrote."""
        if self.combination is None and self.learning is None:
            raise PredictError("nothing to load into: this Predictor neither combines nor learns")
        try:
            with np.load(path, allow_pickle=False) as data:
                state = {key: data[key] for key in data.files}
            if self.combination is not None:
                self.combination.load_state(state)
            if self.learning is not None:
                head = {k[len(_HEAD) :]: v for k, v in state.items() if k.startswith(_HEAD)}
                self.learning.load_state(head)
        except (OSError, ValueError, KeyError) as err:
            raise PredictError(f"{path}: not what save_learned wrote ({err})") from err

    def _motion(self, pose: Any) -> np.ndarray | None:
        """Motion since the previous update in cells, ``None`` when either pose is unknown."""
        previous = self._pose
        try:
            self._pose = None if pose is None else np.asarray(pose, dtype=np.float64).reshape(3)
        except (TypeError, ValueError) as err:  # numpy's own words name no pose
            raise PredictError(f"pose must be three numbers (x, y, yaw), got {pose!r}") from err
        if previous is None or self._pose is None:
            return None
        motion, known = relative_motions(np.stack([previous, self._pose]))
        return metres_to_cells(motion[1], self.grid.res) if known[1] else None

    def _maps(self, item: Scan | tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        if isinstance(item, Scan):
            return rasterize(item, self.grid)
        occupancy, visibility = (np.asarray(a) for a in item)
        if occupancy.shape != self.grid.shape or visibility.shape != self.grid.shape:
            raise PredictError(
                f"maps must be {self.grid.shape}, got {occupancy.shape} and {visibility.shape}"
            )
        return occupancy, visibility

    @property
    def combined_from(self) -> int | None:
        """The first frame ahead the online combination decides (1: all of them; ``None``:
        it does not combine)."""
        return None if self.combination is None else self.combination.first

    def update(self, item: Scan | tuple[np.ndarray, np.ndarray], pose: Any = None) -> Prediction:
        """Feed one scan (or its ``(occupancy, visibility)`` maps, for a model without
        ``subcell_input``: the bundled one has it) and predict what comes next; ``pose``
        ``(x, y, yaw)``: the sensor pose at this scan, for ego-motion models."""
        occupancy, visibility = self._maps(item)
        subcell = None
        if takes_subcell(self.backend.capabilities.input_channels):
            if not isinstance(item, Scan):
                raise PredictError(
                    "this model also uses where each return lies inside its cell "
                    "(subcell_input): give update a Scan, not maps"
                )
            subcell = subcell_batch(item.ranges[None], item.geometry, self.grid)[0]
        scan = item if isinstance(item, Scan) else None
        wants_returns = self.engine.wants_returns and scan is not None
        step = self.engine.step(
            Frame(
                occupancy,
                visibility,
                subcell=subcell,
                returns=scan_points(scan) if wants_returns else None,
                motion=self._motion(pose) if self.uses_motion else None,
                source="none" if pose is None else "pose",
                pace=None if scan is None else self._clock.update(scan.stamp_ns),
            )
        )
        ahead = self.engine.roll(step, self.horizon)
        probability, decided = ahead.probability, ahead.decided
        if self.combination is not None:
            assert self.engine.tracker is not None  # the policy carries tracked objects
            combined = self.combination.step(
                self.engine.tracker, step, ahead, occupancy, visibility
            )
            probability = self.combination.joined(probability, combined.probability)
            decided = self.combination.joined(decided, combined.decided)
        flow = step.flow
        return Prediction(
            probability=probability[0],
            occupied=decided[0] >= THRESHOLD,
            backward_flow=None if flow is None else flow[:2],
            forward_flow=None if flow is None else flow[2:],
            horizon=probability,
            horizon_occupied=decided >= THRESHOLD,
            occupancy=np.asarray(occupancy, bool),
            visibility=np.asarray(visibility, bool),
            ego_compensated=step.motion is not None,
            moving_threshold=self.moving_threshold,
            stamp_ns=0 if scan is None else int(scan.stamp_ns),
            step_ns=self._clock.step_ns,
            tracks=None if step.tracks is None else step.tracks.metric(self._clock.step_ns),
            ahead_motion=None if step.ahead is None else np.array(step.ahead, np.float64),
        )
