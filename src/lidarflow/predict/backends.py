"""Inference backends for :class:`~lidarflow.predict.predictor.Predictor`: PyTorch or ONNX Runtime.

Both run one step on NumPy in and out as :mod:`lidarflow.predict.step` defines it. Each says
what the model takes and gives (:class:`~lidarflow.models.config.Capabilities`) and an
occupancy head's warp gain.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from lidarflow.errors import ModelError, PredictError, ScanError
from lidarflow.models.config import Capabilities
from lidarflow.models.weights import check_decision_offset
from lidarflow.predict.logits import shifted_probability
from lidarflow.predict.step import StepInputs, StepOutput
from lidarflow.scan import GridSpec

#: ONNX metadata key (value ``"true"``) of an ego-motion model that may run without poses
#: (written by :func:`lidarflow.outputs.export.export_onnx`).
POSES_OPTIONAL_KEY = "lidarflow.poses_optional"
#: ONNX metadata key of an occupancy-head model's decision: JSON ``{"offset": a, "online": bool,
#: "gain": g, "calibrated": true}``, the policy it ships with and what the Predictor needs to
#: choose the offsets online. Older files (no ``calibrated``) output the
#: probability decided with ``offset``, which the backend takes back out; files marked before
#: ``gain`` was added try the moved map only.
DECISION_KEY = "lidarflow.decision"
#: ONNX metadata key of the grid the model was exported for: JSON ``{"height", "width", "res"}``
#: (files exported before it existed say only their size, in the graph's shapes).
GRID_KEY = "lidarflow.grid"
#: ONNX metadata key (value ``"false"``) of a model whose four flow channels are no flow of its
#: own (LiDAR-FlowNet without its flow network: zero, or the platform's motion): the Predictor
#: reports no flow and no moving cells for it. Unmarked files with flow channels estimate flow.
FLOW_KEY = "lidarflow.flow"

__all__ = [
    "DECISION_KEY",
    "FLOW_KEY",
    "GRID_KEY",
    "POSES_OPTIONAL_KEY",
    "OnnxBackend",
    "TorchBackend",
    "load_backend",
    "recorded_grid",
    "resolve_device",
    "split_step_inputs",
]


def recorded_grid(card: dict[str, Any]) -> GridSpec | None:
    """The grid a model's ``model.json`` says it was trained on, ``None`` where it says none."""
    grid = card.get("grid")
    try:
        return GridSpec(int(grid["height"]), int(grid["width"]), float(grid["res"]))
    except (KeyError, TypeError, ValueError, ScanError):
        return None


def split_step_inputs(inputs: list[Any]) -> tuple[list[str], list[Any]]:
    """``(motion input names, state inputs)`` of a step graph's inputs: ``maps``, then for
    ego-motion graphs ``motion`` and (files exported since it exists) ``next_motion``, then the
    states (see :mod:`lidarflow.outputs.export`)."""
    motions: list[str] = []
    for name in ("motion", "next_motion"):
        if len(inputs) > 1 + len(motions) and inputs[1 + len(motions)].name == name:
            motions.append(name)
    return motions, list(inputs[1 + len(motions) :])


class TorchBackend:
    """Runs a :class:`~lidarflow.models.recurrent.RecurrentMapModel` with PyTorch."""

    def __init__(self, model: Any, device: str = "cpu", threads: int | None = None) -> None:
        import torch

        if threads:
            torch.set_num_threads(threads)
        self.torch = torch
        self.device = torch.device(device)
        self.model = model.to(self.device).eval()
        self.capabilities: Capabilities = model.capabilities
        self.gain: float | None = model.warp_gain()
        # The policy a model ships with is in its model.json, not in its weights.
        self.decision: dict[str, Any] | None = None

    def init_state(self, height: int, width: int) -> Any:
        return self.model.init_state(1, height, width, device=self.device)

    def run(self, inputs: StepInputs, state: Any) -> StepOutput:
        """One step (:class:`~lidarflow.predict.step.StepInputs`)."""
        motion, next_motion = inputs.motion, inputs.next_motion
        with self.torch.inference_mode():
            x = self.torch.from_numpy(inputs.maps).to(self.device)
            if self.capabilities.ego_motion:
                m, n = (
                    None
                    if a is None
                    else self.torch.as_tensor(
                        a, dtype=self.torch.float32, device=self.device
                    ).reshape(1, 3)
                    for a in (motion, next_motion)
                )
                out, state = self.model.step(x, state, m, n)
            else:
                out, state = self.model.step(x, state)
            probability = self.model.predict_next(x, out)
        return StepOutput(probability.float().cpu().numpy(), out.float().cpu().numpy(), state)


class OnnxBackend:
    """Runs an ONNX file written by :func:`~lidarflow.outputs.export.export_onnx` with
    onnxruntime (no PyTorch needed)."""

    def __init__(self, path: str | Path, threads: int | None = None) -> None:
        import onnxruntime as ort

        path = Path(path)
        if not path.exists():
            raise PredictError(f"{path}: no such ONNX file")
        options = ort.SessionOptions()
        if threads:
            options.intra_op_num_threads = threads
        # A step's operators are small (a 100 x 100 map): onnxruntime's idle workers spinning
        # for the next one take the core the caller needs beside a busy process
        # (docs/research/step_speed). Blocking workers cost a wake-up instead.
        options.add_session_config_entry("session.intra_op.allow_spinning", "0")
        try:
            self.session = ort.InferenceSession(
                str(path), options, providers=["CPUExecutionProvider"]
            )
        except Exception as err:  # onnxruntime raises its own exception classes
            raise PredictError(f"{path}: not a loadable ONNX model ({err})") from err
        inputs = self.session.get_inputs()
        if not inputs or inputs[0].name != "maps":
            raise PredictError(f"{path}: not a lidarflow step graph (first input is not 'maps')")
        self.motion_inputs, state_inputs = split_step_inputs(inputs)
        marks = self.session.get_modelmeta().custom_metadata_map
        # Files exported before the mark existed have none: no decision of their own.
        decision = json.loads(marks[DECISION_KEY]) if DECISION_KEY in marks else None
        if decision is not None and decision.get("offset_free") is not None:
            raise PredictError(
                f"{path}: exported with a decision offset for free cells, an option since "
                "removed; export the model again"
            )
        #: The decision the file ships with (``{"offset", "online", "movers"}``), ``None`` if
        #: unmarked.
        self.decision = (
            None
            if decision is None
            else {
                "offset": check_decision_offset(decision["offset"], f"{path}: {DECISION_KEY}"),
                "online": bool(decision.get("online")),
                "movers": bool(decision.get("movers")),
            }
        )
        gain = None if decision is None else decision.get("gain")
        self.gain = None if gain is None else float(gain)
        # In an older export (no "calibrated") the graph's probability carries the fixed offset.
        self._baked_offset = 0.0
        if decision is not None and not decision.get("calibrated"):
            self._baked_offset = self.decision["offset"]
        self.state_shapes = [tuple(i.shape) for i in state_inputs]
        self.grid_shape = tuple(inputs[0].shape[-2:])
        self.grid = (
            recorded_grid({"grid": json.loads(marks[GRID_KEY])}) if GRID_KEY in marks else None
        )
        out_channels = int(self.session.get_outputs()[1].shape[1])
        self.capabilities = Capabilities(
            input_channels=int(inputs[0].shape[1]),
            out_channels=out_channels,
            flow=out_channels >= 4 and marks.get(FLOW_KEY) != "false",
            occupancy_head=decision is not None,
            ego_motion=bool(self.motion_inputs),
            poses_optional=marks.get(POSES_OPTIONAL_KEY) == "true",
        )
        self._check_finite(path)

    def _check_finite(self, path: Path) -> None:
        """Refuse a file whose weights are not finite: such a model loads and runs, and breaks
        far from the cause. One step on empty maps from a zero state must give finite outputs
        (a NaN weight reaches them: NaN times zero is NaN); the ``onnx`` package, where it is
        installed (the torch extra), then names the tensors."""
        h, w = self.grid_shape
        state = self.init_state(int(h), int(w))
        maps = np.zeros((1, self.capabilities.input_channels, int(h), int(w)), np.float32)
        outputs = self.run(StepInputs(maps), state)
        if all(np.isfinite(np.asarray(a)).all() for a in (outputs[0], outputs[1], *outputs[2])):
            return
        from lidarflow.models.finite import check_finite_onnx

        with contextlib.suppress(ImportError):  # no onnx package: the probe's own words
            check_finite_onnx(path)
        raise ModelError(
            f"{path}: weights are not finite (one step on empty maps gives NaN or inf); the "
            "file is damaged or its training diverged: export an earlier checkpoint"
        )

    def init_state(self, height: int, width: int) -> Any:
        if (height, width) != self.grid_shape:
            raise PredictError(
                f"this ONNX model was exported for a {self.grid_shape[0]}x{self.grid_shape[1]} "
                f"grid, not {height}x{width}; run it on that grid (--grid {self.grid_shape[0]} "
                "and its --res) or export again with --grid"
            )
        return [np.zeros(s, np.float32) for s in self.state_shapes]

    def run(self, inputs: StepInputs, state: Any) -> StepOutput:
        """One step (:class:`~lidarflow.predict.step.StepInputs`); a file exported before graphs
        took ``next_motion`` guesses the last motion again whatever ``next_motion`` says."""
        motion, next_motion = inputs.motion, inputs.next_motion
        feeds = {"maps": inputs.maps, **{f"state{i}": s for i, s in enumerate(state)}}
        if self.capabilities.ego_motion:  # zeros: no motion known, the same as no compensation
            m = np.zeros(3, np.float32) if motion is None else np.asarray(motion, np.float32)
            feeds["motion"] = m.reshape(1, 3)
            if "next_motion" in self.motion_inputs:
                n = m if next_motion is None else np.asarray(next_motion, np.float32)
                feeds["next_motion"] = n.reshape(1, 3)
        probability, out, *next_state = self.session.run(None, feeds)
        if self._baked_offset:
            probability = shifted_probability(probability, -self._baked_offset)
        return StepOutput(probability, out, next_state)


def resolve_device(name: str) -> str:
    """``auto`` -> ``cuda`` where PyTorch sees a GPU, else ``cpu``; ``cpu``, ``cuda`` and
    ``cuda:N`` as given, once checked (:class:`PredictError` in one line otherwise)."""
    if name == "cpu":
        return name
    if name != "auto" and name != "cuda" and not name.startswith("cuda:"):
        raise PredictError(f"unknown device {name!r}: auto, cpu, cuda or cuda:N")
    try:
        import torch
    except ImportError:  # the core install: ONNX on the CPU
        torch = None
    if torch is None or not torch.cuda.is_available():
        if name == "auto":
            return "cpu"
        raise PredictError(f"--device {name} asked for, but PyTorch sees no CUDA device")
    return "cuda" if name == "auto" else name


def load_backend(
    source: str | Path | None, threads: int | None = None, device: str = "cpu"
) -> tuple[Any, dict[str, Any]]:
    """The backend that runs ``source`` and its card (``model.json``'s record; for an ONNX file
    what its marks say): an ``.onnx`` file on onnxruntime; a head-only model (the bundled one)
    on the CPU in NumPy (:class:`~lidarflow.predict.headstep.HeadStepBackend`), the bundled
    one read from its files without PyTorch; any other run folder or weights file on PyTorch.

    Raises:
        MissingExtraError: PyTorch weights, and PyTorch not installed.
    """
    from lidarflow.extras import missing_extra, torch_available
    from lidarflow.models.presets import bundled_onnx, is_bundled

    if is_bundled(source) and device == "cpu":
        # Read without PyTorch, with it installed too: the same step and numbers, and no
        # second spent importing it before the first prediction.
        head, card = _bundled_head()
        if head is not None:
            torch = sys.modules.get("torch")  # None where an import of it was blocked
            if threads and torch is not None:  # as TorchBackend: the setting is the process's
                torch.set_num_threads(threads)
            return head, card
    if is_bundled(source) and not torch_available():
        path, card = bundled_onnx()
        return OnnxBackend(path, threads), card
    if source is not None and Path(source).suffix.lower() == ".onnx":
        backend = OnnxBackend(source, threads)
        card = {"model": "onnx", "weights_path": str(source), "decision": backend.decision}
        if backend.grid is not None:
            card["grid"] = dataclasses.asdict(backend.grid)
        return backend, card
    try:
        from lidarflow.models.presets import resolve_model

        net, card = resolve_model(source)
    except ImportError as err:
        what = "the bundled model" if is_bundled(source) else f"the model {source}"
        missing = missing_extra(err, what)
        if missing is None:
            raise
        raise missing from err
    from lidarflow.predict.headstep import HeadStepBackend, supports

    if device == "cpu" and supports(net):
        # The head alone: its step in NumPy, without PyTorch's per-operator overhead; the same
        # numbers within 1e-5 (tests/predict/test_headstep.py).
        return HeadStepBackend(net, threads), card
    return TorchBackend(net, device, threads), card


def learning_backend(backend: Any) -> Any:
    """The backend a model learns on (:mod:`lidarflow.predict.learning`): ``backend`` itself
    where it runs a head's step in NumPy, as every head-only model on the CPU does (the bundled
    one on the core install too, :func:`load_backend`).

    Raises:
        PredictError: any other model (a flow model, an ONNX file, a model on a GPU).
    """
    from lidarflow.predict.headstep import HeadStepBackend

    if isinstance(backend, HeadStepBackend):
        return backend
    raise PredictError(
        "learning on the stream needs a head-only model run in NumPy on the CPU (as the "
        "bundled one is), not this one"
    )


def _bundled_head() -> tuple[Any, dict[str, Any]]:
    """The bundled model's head step read from its own files without PyTorch (checked against
    the recorded checksum) and its card; ``(None, card)`` where it is not a head-only model."""
    from lidarflow.models.presets import BUNDLED, bundled_model_dir
    from lidarflow.models.weights import sha256
    from lidarflow.predict.headstep import HeadStepBackend, read_head

    folder = bundled_model_dir()
    weights = folder / "model.safetensors"
    checksum = sha256(weights)
    if BUNDLED.weights_sha256 and checksum != BUNDLED.weights_sha256:
        raise ModelError(f"{weights}: checksum differs from the record; the file is damaged")
    card = json.loads((folder / "model.json").read_text())
    head = read_head(card, weights)
    card.update(weights_path=str(weights), weights_sha256=checksum)
    return (None if head is None else HeadStepBackend(head)), card
