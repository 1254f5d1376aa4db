"""ONNX export of one streaming step, the recurrent state as explicit inputs and outputs.

Graph: inputs ``maps (1, C, H, W)`` (``C`` the model's ``input_channels``: 2, ``(O, V)``, or
4 with ``subcell_input``), ``state0..stateN-1``; outputs ``probability (1, 1, H, W)``
(next-map occupancy), ``out (1, C, H, W)`` (flow channels for LiDAR-FlowNet, the logit for
DeepTracking, the logit and its step's KL for SOGMP) and ``next_state0..``. The grid size is
fixed at export time (the warp's sampling grid is a constant of the graph). A stochastic model
is exported in eval mode, so the graph holds its mean path: SOGMP decodes its latent's mean,
no noise input (its samples are PyTorch's, :meth:`lidarflow.models.sogmp.SOGMP.sample`).

Ego-motion models (:class:`~lidarflow.models.EgoCompensated`) take one more input after
``maps``: ``motion (1, 3)``, this frame's pose in the previous frame's, ``dx, dy`` in cells and
``dyaw`` in radians (zeros: no motion / unknown), then ``next_motion (1, 3)``, the guess of the
motion to the next frame: ``motion`` again (constant velocity, as in PyTorch), scaled down after
a long step in time (:func:`lidarflow.motion.pacing.paced_motion`; files exported before this input
existed take ``motion`` again). One built with ``poses_optional`` (it may run without
poses: the Predictor then matches the motion from the scans) says so in the file's metadata, key
:data:`POSES_OPTIONAL_KEY`. An occupancy-head model's ``probability`` is calibrated (no
offset); the decision policy it ships with (offset, online or not) and its warp gain are in
:data:`DECISION_KEY`, so that the Predictor decides as PyTorch does. A model without a flow
network keeps the four flow channels (zero, or the platform's motion) and is marked
:data:`~lidarflow.predict.backends.FLOW_KEY` ``"false"``: the Predictor reports no flow for it.
"""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import torch
from torch import Tensor, nn

from lidarflow.errors import PredictError
from lidarflow.models.recurrent import RecurrentMapModel
from lidarflow.predict.backends import DECISION_KEY, FLOW_KEY, GRID_KEY, POSES_OPTIONAL_KEY
from lidarflow.predict.decision import DecisionPolicy

__all__ = ["DECISION_KEY", "OPSET", "POSES_OPTIONAL_KEY", "StepGraph", "copy_marks", "export_onnx"]

OPSET = 17


class StepGraph(nn.Module):
    """``forward(maps, *state) -> (probability, out, *next_state)``: what the ONNX file holds."""

    def __init__(self, model: RecurrentMapModel) -> None:
        super().__init__()
        self.model = model

    def forward(self, maps: Tensor, *state: Tensor) -> tuple[Tensor, ...]:
        out, next_state = self.model.step(maps, tuple(state))
        return (self.model.predict_next(maps, out), out, *next_state)


class EgoStepGraph(StepGraph):
    """``forward(maps, motion, next_motion, *state)`` for ego-motion models."""

    def forward(  # type: ignore[override]
        self, maps: Tensor, motion: Tensor, next_motion: Tensor, *state: Tensor
    ) -> tuple[Tensor, ...]:
        out, next_state = self.model.step(maps, tuple(state), motion, next_motion)  # type: ignore[call-arg]
        return (self.model.predict_next(maps, out), out, *next_state)


def export_onnx(
    model: RecurrentMapModel,
    path: str | Path,
    height: int = 100,
    width: int = 100,
    res: float | None = None,
    decision: DecisionPolicy | None = None,
) -> Path:
    """Write ``model``'s streaming step to ``path`` as ONNX (opset :data:`OPSET`); ``res``, the
    cell size it is meant for, goes into the file's metadata (:data:`GRID_KEY`) beside the
    size, so that the Predictor runs it on that grid; ``decision``, the policy an occupancy
    head ships with (default: at 0.4 as it is), into :data:`DECISION_KEY`."""
    path = Path(path)
    if not path.parent.exists():
        raise PredictError(f"{path.parent}: no such folder for the ONNX file")
    caps = model.capabilities
    ego = caps.ego_motion
    model = model.eval()
    graph = EgoStepGraph(model) if ego else StepGraph(model)
    state = model.init_state(1, height, width)
    maps = torch.zeros(1, caps.input_channels, height, width)
    extra = (torch.zeros(1, 3), torch.zeros(1, 3)) if ego else ()  # motion, next_motion
    motions = ["motion", "next_motion"] if ego else []
    names_in = ["maps", *motions, *[f"state{i}" for i in range(len(state))]]
    names_out = ["probability", "out", *[f"next_state{i}" for i in range(len(state))]]
    with warnings.catch_warnings():
        # The tracer warns that the grid size becomes a constant: that is intended (see above).
        warnings.simplefilter("ignore")
        try:
            torch.onnx.export(
                graph,
                (maps, *extra, *state),
                str(path),
                input_names=names_in,
                output_names=names_out,
                opset_version=OPSET,
                dynamo=False,
            )
        except Exception as err:  # the exporter raises many types
            raise PredictError(f"ONNX export failed: {type(err).__name__}: {err}") from err
    marks = {}
    if res is not None:
        marks[GRID_KEY] = json.dumps({"height": height, "width": width, "res": res})
    if caps.poses_optional:
        marks[POSES_OPTIONAL_KEY] = "true"
    if caps.out_channels >= 4 and not caps.flow:  # the flow channels without a flow network
        marks[FLOW_KEY] = "false"
    if caps.occupancy_head:
        record = (decision or DecisionPolicy()).to_record()
        marks[DECISION_KEY] = json.dumps({**record, "gain": model.warp_gain(), "calibrated": True})
    if marks:
        _write_marks(path, marks)
    return path


def _write_marks(path: Path, marks: dict[str, str]) -> None:
    import onnx

    model = onnx.load(str(path))
    onnx.helper.set_model_props(model, marks)
    onnx.save(model, str(path))


def copy_marks(source: str | Path, target: str | Path) -> None:
    """Copy ``source``'s lidarflow metadata (poses optional, decision) to the ONNX file
    ``target``, so that a graph rewritten from another (int8) keeps it."""
    import onnx

    marks = {
        p.key: p.value
        for p in onnx.load(str(source)).metadata_props
        if p.key.startswith("lidarflow.")
    }
    if marks:
        _write_marks(Path(target), marks)
