"""ONNX export of one streaming step, the recurrent state as explicit inputs and outputs.

Inputs ``maps (1, C, H, W)`` (``C`` the model's ``input_channels``), then for ego-motion models
(:class:`~lidarflow.models.EgoCompensated`) ``motion (1, 3)`` (this frame's pose in the previous
one's: ``dx, dy`` in cells, ``dyaw`` in radians; zeros: unknown) and ``next_motion (1, 3)``
(the guess of the next frame's, :func:`lidarflow.motion.pacing.paced_motion`), then
``state0..``. Outputs ``probability (1, 1, H, W)`` (next-map occupancy), ``out (1, C, H, W)``
(LiDAR-FlowNet's flow channels, DeepTracking's logit, SOGMP's logit and KL) and
``next_state0..``. The grid size is fixed at export (the warp's
sampling grid is a constant of the graph); a stochastic model exports its mean path.

Metadata (:mod:`lidarflow.predict.backends` keys) tells the Predictor the grid, whether poses
are optional, the decision policy and warp gain of an occupancy head (whose ``probability`` is
calibrated), and that a model without a flow network reports no flow.
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
