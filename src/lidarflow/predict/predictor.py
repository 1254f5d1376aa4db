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
the scans where no pose is given (:class:`lidarflow.data.scanmatch.ScanOdometry`: refined on the
returns when ``update`` is given a :class:`~lidarflow.scan.Scan`). Otherwise, without a pose
(``None`` or NaN) that step is not compensated (``Prediction.ego_compensated`` is
False), as a model without odometry would run; horizon steps beyond the first repeat the last
motion.

A model built with ``subcell_input`` also sees where each return lies inside its cell
(:func:`lidarflow.scan.subcell_batch`), which only a :class:`~lidarflow.scan.Scan` carries: give
its ``update`` scans, not maps.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from lidarflow.data.gaps import StepClock, paced_motion
from lidarflow.data.motion import OdometryCheck, metres_to_cells, relative_motions
from lidarflow.data.scanalign import scan_points
from lidarflow.data.scanmatch import ScanOdometry, checked_motion
from lidarflow.errors import PredictError
from lidarflow.evaluate.metrics import THRESHOLD
from lidarflow.evaluate.online import (
    OnlineDecision,
    OnlineDecisionConfig,
    decision_for,
    moved_last_map,
)
from lidarflow.predict.backends import OnnxBackend, TorchBackend, recorded_grid
from lidarflow.scan import GridSpec, Scan, rasterize, subcell_batch, takes_subcell
from lidarflow.segmentation import MOVING_THRESHOLD, moving_mask

__all__ = ["Prediction", "Predictor"]


@dataclass(frozen=True)
class Prediction:
    """What one update returns.

    Attributes:
        probability: ``(H, W)`` probability that each cell is occupied in the next frame.
        occupied: ``probability >= 0.4`` (the project's decision threshold).
        backward_flow, forward_flow: ``(2, H, W)`` flow in cells (column, row), ``None`` for
            models that predict occupancy directly (DeepTracking).
        horizon: ``(K, H, W)`` probabilities 1..K frames ahead (``horizon[0] is probability``).
        occupancy, visibility: the maps of the frame just given.
        ego_compensated: an ego-motion model was given the motion since the previous scan (from
            the pose, or matched from the scans).
        moving_threshold: cells per frame of motion of its own above which a cell is moving.
    """

    probability: np.ndarray
    occupied: np.ndarray
    backward_flow: np.ndarray | None
    forward_flow: np.ndarray | None
    horizon: np.ndarray
    occupancy: np.ndarray
    visibility: np.ndarray
    ego_compensated: bool = False
    moving_threshold: float = MOVING_THRESHOLD

    @cached_property
    def moving(self) -> np.ndarray | None:
        """``(H, W)`` bool, the occupied cells of the frame just given that move on their own
        (forward flow less the platform's motion longer than ``moving_threshold`` cells;
        :func:`lidarflow.segmentation.moving_mask`); ``None`` for models without flow.

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
            no PyTorch needed), or ``None`` for the bundled pretrained model.
        grid: the map grid (default: the one the model was trained on, as its model.json or
            the ONNX file's metadata says; else 100 x 100 at 0.1 m, the bundled model's).
        horizon: frames ahead to predict; beyond the first, predictions are fed back as input.
        threads: CPU threads for inference, process-wide (default 1: many times faster beside
            a busy process, benchmarks/results/threads.json; ``None``: leave PyTorch's setting).
        moving_threshold: cells per frame of motion of its own above which an occupied cell is
            reported moving (:data:`lidarflow.segmentation.MOVING_THRESHOLD` by default).
        check_odometry: for a model that may run without poses (``poses_optional``, the bundled
            one): stop compensating while the poses disagree with the scans
            (:class:`~lidarflow.data.motion.OdometryCheck`). Off: every pose given is used.
        scan_odometry: for such a model, where no pose is given, take the motion from the scans
            (:class:`lidarflow.data.scanmatch.ScanOdometry`: the maps matched, and refined on
            the returns where ``update`` is given a :class:`~lidarflow.scan.Scan`); off: those
            steps run uncompensated.
        online_decision: re-decide an occupancy-head model's next map with the decision offsets
            that have done best on this stream so far (:mod:`lidarflow.evaluate.online`; a
            roll-out feeds back the decided map and re-decides every step with the same
            choice). ``None``: where
            the model asks for it (``online_decision`` in its kwargs or the ONNX file's marks);
            an :class:`~lidarflow.evaluate.online.OnlineDecisionConfig`: always, with that grid
            and those constants.
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
    ) -> None:
        if horizon < 1:
            raise PredictError(f"horizon must be >= 1, got {horizon}")
        if not moving_threshold >= 0:
            raise PredictError(f"moving_threshold must be >= 0 cells, got {moving_threshold}")
        self.moving_threshold = moving_threshold
        self.horizon = horizon
        self.backend: Any
        if model is not None and Path(model).suffix.lower() == ".onnx":
            self.backend = OnnxBackend(model, threads)
            self.card: dict[str, Any] = {"model": "onnx", "weights_path": str(model)}
            recorded = self.backend.grid
        else:
            from lidarflow.models.presets import resolve_model

            net, self.card = resolve_model(model)
            self.backend = TorchBackend(net, device, threads)
            recorded = recorded_grid(self.card)
        # The grid the model was trained (or exported) for, unless told otherwise.
        self.grid = grid or recorded or GridSpec()
        self._state: Any = None
        self._pose: np.ndarray | None = None
        # See lidarflow.evaluate.model_method: the same check, the same decisions.
        self._odometry = OdometryCheck() if check_odometry else None
        self.scan_odometry = scan_odometry
        self._scans = ScanOdometry(self.grid.res)
        # Scans' stamps: after a long step the last motion spans it, and the guess of the next
        # one is scaled to a typical step (lidarflow.data.gaps, as evaluate does).
        self._clock = StepClock()
        self.online = self._online_decision(online_decision)

    def _online_decision(self, wanted: bool | OnlineDecisionConfig | None) -> OnlineDecision | None:
        try:
            return decision_for(getattr(self.backend, "decision", None), wanted)
        except ValueError as err:
            raise PredictError(
                "the online decision needs an occupancy-head model (an ONNX file exported "
                "before lidarflow marked the decision offsets in it: export it again)"
            ) from err

    @property
    def uses_motion(self) -> bool:
        """Whether the model compensates ego motion (then give ``update`` the sensor pose)."""
        return bool(getattr(self.backend, "uses_motion", False))

    @property
    def poses_optional(self) -> bool:
        """Whether an ego-motion model may run without poses (without one it takes the motion
        from the scans, ``scan_odometry``, else runs uncompensated)."""
        return bool(getattr(self.backend, "poses_optional", False))

    def reset(self) -> None:
        """Forget the past: the next update starts from a zero state."""
        self._state = None
        self._pose = None
        if self._odometry is not None:
            self._odometry.reset()
        self._scans.reset()
        self._clock.reset()
        if self.online is not None:
            self.online.reset()

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

    def update(self, item: Scan | tuple[np.ndarray, np.ndarray], pose: Any = None) -> Prediction:
        """Feed one scan (or its ``(occupancy, visibility)`` maps, for a model without
        ``subcell_input``: the bundled one has it) and predict what comes next; ``pose``
        ``(x, y, yaw)``: the sensor pose at this scan, for ego-motion models."""
        occupancy, visibility = self._maps(item)
        maps = np.stack([occupancy, visibility]).astype(np.float32)[None]
        subcell = takes_subcell(self.backend.input_channels)
        if subcell and not isinstance(item, Scan):
            raise PredictError(
                "this model also uses where each return lies inside its cell (subcell_input): "
                "give update a Scan, not maps"
            )
        if subcell:
            extra = subcell_batch(item.ranges[None], item.geometry, self.grid)
            maps = np.concatenate([maps, extra.astype(np.float32)], axis=1)
        if self._state is None:
            self._state = self.backend.init_state(*self.grid.shape)
        motion = self._motion(pose) if self.uses_motion else None
        scans = self._scans if self.poses_optional and self.scan_odometry else None
        points = scan_points(item) if scans is not None and isinstance(item, Scan) else None
        pace = self._clock.update(item.stamp_ns) if isinstance(item, Scan) else None
        if pose is None and scans is not None:
            motion = scans.update(occupancy, points)
        if self.poses_optional and self._odometry is not None:
            # Odometry that disagrees with the scans (or jumps) is replaced by the scans' motion.
            motion, _ = checked_motion(
                self._odometry, scans, occupancy, motion, pose is not None, points, pace
            )
        elif pose is not None and scans is not None:
            scans.observe(occupancy, points)
        guess = paced_motion(motion, pace)  # None: the last motion again
        probability, out, self._state = self.backend.run(maps, self._state, motion, guess)
        flow = out[0, :4] if self.backend.out_channels >= 4 else None
        future = [probability[0, 0]]
        if self.online is not None:
            moved = moved_last_map(occupancy, None if flow is None else flow[:2])
            future[0] = self.online.update(future[0], occupancy, visibility, moved)
        # Roll forward on a copy of the state: the fed-back predictions must not leak into
        # the state that the next real scan continues from. With the online decision each
        # step is re-decided with its current choice (see lidarflow.evaluate.horizon).
        state = self._state
        ahead = motion if guess is None else guess  # each step ahead is one typical step
        for _ in range(self.horizon - 1):
            fed = np.zeros_like(maps)  # a predicted map has no returns: subcell zeros
            fed[0, 0], fed[0, 1] = future[-1], visibility
            next_probability, out_k, state = self.backend.run(fed, state, ahead)
            if self.online is not None:
                flow_k = out_k[0, :2] if self.backend.out_channels >= 4 else None
                moved = moved_last_map(future[-1], flow_k)
                future.append(self.online.apply(next_probability[0, 0], future[-1], moved))
            else:
                future.append(next_probability[0, 0])
        occupied_now = np.asarray(occupancy, bool)
        return Prediction(
            probability=future[0],
            occupied=future[0] >= THRESHOLD,
            backward_flow=None if flow is None else flow[:2],
            forward_flow=None if flow is None else flow[2:],
            horizon=np.stack(future),
            occupancy=occupied_now,
            visibility=np.asarray(visibility, bool),
            ego_compensated=motion is not None,
            moving_threshold=self.moving_threshold,
        )
