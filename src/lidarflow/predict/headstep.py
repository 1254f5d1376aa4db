"""The step of an occupancy-head model without a flow network, in NumPy.

Such a model (the bundled one since v9, :class:`~lidarflow.models.flownet.LidarFlowNet` with
``flow=None``, ego-compensated or not) does a few arithmetic operations per cell: move the
state by the platform's motion, update the memories, find the constant-velocity shift, a 1x1
layer or two, move the logit into the next frame. In eager PyTorch those are dozens of small
operators whose overhead outweighs the arithmetic (``docs/research/step_speed/``); here it is
a few fused NumPy operations on the same weights, the gathers of the rigid warps kept from step
to step (:func:`lidarflow.geometry.rigid_sampler`), and the shift counted on the occupied cells only
(:func:`lidarflow.baselines.best_rigid_shift`).

Generic over :class:`~lidarflow.models.config.HeadConfig` as it stands (memories, the
constant-velocity input and moved memories, the hidden layer, the visibility and sub-cell
inputs), with the weights read from the model (:func:`supports` says no to anything else: a
flow network, a head of another kind, a config field this step does not know, a model not in
float32 on the CPU; :func:`~lidarflow.predict.backends.load_backend` then runs the model on
PyTorch), or from its files without PyTorch (:func:`read_head`).
tests/predict/test_headstep.py holds it to the PyTorch step within 1e-5.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np

from lidarflow.baselines import best_rigid_shift
from lidarflow.geometry import Sampler, rigid_positions, rigid_sampler
from lidarflow.models.config import (
    OCCUPANCY_FILL_LOGIT,
    Capabilities,
    HeadConfig,
    ModelSpec,
)
from lidarflow.models.weights import read_safetensors, upgrade_state
from lidarflow.predict.step import StepInputs, StepOutput

__all__ = ["HeadStepBackend", "HeadTrace", "HeadWeights", "read_head", "supports"]

#: The HeadConfig fields this step computes; a head with any other is left to PyTorch.
KNOWN_FIELDS = frozenset(
    {
        "memory_decays",
        "constant_velocity_input",
        "shift_memories",
        "hidden_channels",
        "visibility_input",
        "subcell_input",
    }
)
# As lidarflow.ops.shift: a map moved by exactly half a cell holds 0.5, counted on neither side.
_OCCUPIED_ABOVE = 0.5 - 1e-3


def _parts(model: Any) -> tuple[Any, bool] | None:
    """``(head, ego)`` of a head-only flownet (ego-compensated or not), else ``None``."""
    from lidarflow.models.egomotion import EgoCompensated
    from lidarflow.models.flownet import LidarFlowNet
    from lidarflow.models.head import OccupancyHead

    ego = isinstance(model, EgoCompensated)
    inner = model.inner if ego else model
    if type(inner) is not LidarFlowNet or inner.flow is not None:
        return None
    head = inner.head
    if type(head) is not OccupancyHead:
        return None
    return head, ego


def supports(model: Any) -> bool:
    """Whether :class:`HeadStepBackend` computes ``model``'s step (see the module docstring)."""
    parts = _parts(model)
    if parts is None:
        return False
    head = parts[0]
    if {f.name for f in dataclasses.fields(head.config)} != KNOWN_FIELDS:
        return False
    weights = list(head.parameters())
    convs = [head.out] + ([head.hidden] if head.config.hidden_channels else [])
    return all(p.device.type == "cpu" and str(p.dtype) == "torch.float32" for p in weights) and all(
        tuple(c.kernel_size) == (1, 1) and c.groups == 1 for c in convs
    )


_Layers = list[tuple[np.ndarray, np.ndarray]]


@dataclass(frozen=True)
class HeadWeights:
    """What the step of a head-only model is made of: its head's ``config``, ``ego`` (it is
    ego-compensated) and ``poses_optional``, its 1x1 ``layers`` as ``(weight (out, in), bias
    (out, 1))`` float32 arrays (the hidden layer first where it has one) and its ``gain``."""

    config: HeadConfig
    ego: bool
    poses_optional: bool
    layers: _Layers
    gain: float

    @property
    def capabilities(self) -> Capabilities:
        channels = 4 if self.config.subcell_input else 2
        return Capabilities(channels, 5, False, True, self.ego, self.poses_optional)


def _layer_arrays(weight: np.ndarray, bias: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A 1x1 convolution's ``(out, in, 1, 1)`` weight and ``(out,)`` bias as one layer."""
    weight = np.asarray(weight, np.float32)[:, :, 0, 0].copy()
    return weight, np.asarray(bias, np.float32)[:, None].copy()


def _from_model(model: Any) -> HeadWeights:
    """A PyTorch head-only model's (:func:`supports`) weights as arrays."""
    head, ego = _parts(model)  # type: ignore[misc]
    convs = ([head.hidden] if head.config.hidden_channels else []) + [head.out]
    layers = [_layer_arrays(c.weight.detach().cpu().numpy(), c.bias.detach().cpu().numpy())
              for c in convs]  # fmt: skip
    caps = model.capabilities
    return HeadWeights(head.config, ego, caps.poses_optional, layers, float(head.gain.detach()))


def read_head(card: dict[str, Any], weights: str | Any) -> HeadWeights | None:
    """The head-only model a ``model.json`` ``card`` describes, with its ``.safetensors``
    ``weights`` file read without PyTorch; ``None`` for any other kind of model. A
    ``ValueError`` where the file does not hold that model's weights."""
    try:
        spec, _ = ModelSpec.from_kwargs(card["model"], dict(card.get("model_kwargs") or {}), True)
    except (KeyError, TypeError, ValueError):
        return None
    head = spec.head
    if spec.name != "flownet" or spec.flow is not None or head is None:
        return None
    if {f.name for f in dataclasses.fields(head)} != KNOWN_FIELDS:
        return None
    state = upgrade_state(read_safetensors(weights))
    prefix = "inner.head." if spec.ego_motion else "head."
    names = (["hidden"] if head.hidden_channels else []) + ["out"]
    try:
        layers = [
            _layer_arrays(state[f"{prefix}{n}.weight"], state[f"{prefix}{n}.bias"]) for n in names
        ]
        gain = float(state[f"{prefix}gain"])
    except KeyError as err:
        raise ValueError(f"{weights}: no {err.args[0]} among the weights") from err
    return HeadWeights(head, spec.ego_motion, spec.poses_optional, layers, gain)


# OpenBLAS runs a matrix product on one thread below m * n * k = 65536 * 4; above it wakes a
# thread per core, and beside a busy process the head's whole-map product took 9 ms instead of
# 0.09 (its threads wait on each other). A product of ~2 MFLOP cannot gain from a second
# thread, so it goes in slices of columns that stay below that size.
_SINGLE_THREAD_MNK = 65536 * 2


def _layer(weight: np.ndarray, bias: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``weight @ x + bias`` ``(out, cells)`` float32, computed on one thread."""
    out = np.empty((weight.shape[0], x.shape[1]), np.float32)
    step = max(64, _SINGLE_THREAD_MNK // max(1, weight.size))
    for start in range(0, x.shape[1], step):
        np.matmul(weight, x[:, start : start + step], out=out[:, start : start + step])
    out += bias
    return out


def _shifted(maps: np.ndarray, d_col: int, d_row: int) -> np.ndarray:
    """``maps`` ``(C, H, W)`` with their content moved by ``(d_col, d_row)``, zeros entering
    (:func:`lidarflow.ops.shift.apply_shift`)."""
    if d_col == 0 and d_row == 0:
        return maps
    out = np.zeros_like(maps)
    h, w = maps.shape[-2:]
    if abs(d_row) < h and abs(d_col) < w:
        out[:, max(0, d_row) : h + min(0, d_row), max(0, d_col) : w + min(0, d_col)] = maps[
            :, max(0, -d_row) : h + min(0, -d_row), max(0, -d_col) : w + min(0, -d_col)
        ]
    return out


@dataclass(frozen=True, slots=True)
class HeadTrace:
    """What one step computed that the gradient of its prediction needs: ``inputs``, each
    layer's input ``(C, H*W)`` (the features, then the hidden activations after the ReLU);
    ``weighed`` ``(H, W)``, the map the gain weighs; ``sampler``, the move of the logit into the
    next frame (``None``: not moved); ``probability`` ``(H, W)``, the prediction made."""

    inputs: tuple[np.ndarray, ...]
    weighed: np.ndarray
    sampler: Sampler | None
    probability: np.ndarray


class HeadStepBackend:
    """Runs a head-only model's step in NumPy (:func:`supports` says which), as
    :class:`~lidarflow.predict.backends.TorchBackend` does on PyTorch (one step as
    :mod:`lidarflow.predict.step` defines it, ``out`` ``(1, 5, H, W)``) on float32 arrays; the
    state is a list of one ``(1, S, H, W)`` array.

    ``layers`` are the head's 1x1 layers as ``(weight (out, in), bias (out, 1))`` float32
    arrays, which :class:`lidarflow.predict.learning.HeadLearning` changes in place; ``trace``
    is what the last step computed (:class:`HeadTrace`)."""

    def __init__(self, model: Any, threads: int | None = None) -> None:
        if not isinstance(model, HeadWeights):
            if not supports(model):
                raise ValueError("HeadStepBackend runs a head-only flownet's step (supports())")
            model = _from_model(model)
            if threads:  # process-wide, as TorchBackend sets it (this step itself takes one)
                import torch

                torch.set_num_threads(threads)
        c = self.config = model.config
        self._ego = model.ego
        self.capabilities: Capabilities = model.capabilities
        self.gain: float | None = model.gain
        self.decision: dict[str, Any] | None = None  # as TorchBackend: the policy is the card's
        self._decays = np.asarray(c.memory_decays, np.float32).reshape(-1, 1, 1)
        self.layers = [(w.copy(), b.copy()) for w, b in model.layers]
        self.trace: HeadTrace | None = None
        self._state_channels = len(c.memory_decays) + int(c.constant_velocity_input)
        self._fill = float(OCCUPANCY_FILL_LOGIT)
        self._flow_key: tuple[float, ...] | None = None
        self._flow = np.zeros(0, np.float32)

    def init_state(self, height: int, width: int) -> Any:
        return [np.zeros((1, self._state_channels, height, width), np.float32)]

    def run(self, inputs: StepInputs, state: Any) -> StepOutput:
        """One step (:class:`~lidarflow.predict.step.StepInputs`)."""
        maps = np.asarray(inputs.maps, np.float32)
        motion, next_motion = inputs.motion, inputs.next_motion
        if maps.ndim != 4 or maps.shape[0] != 1:
            raise ValueError(f"maps must be (1, C, H, W), got {maps.shape}")
        h, w = maps.shape[-2:]
        past = state[0][0]
        if not self._ego:
            motion = next_motion = None
        if motion is not None:
            past = rigid_sampler(motion, h, w)(past)
        residual, kept, inputs = self._head(maps[0], past)
        nxt = motion if next_motion is None else next_motion
        occupancy = maps[0, 0:1]
        out = np.zeros((1, 5, h, w), np.float32)
        sampler = None if nxt is None else rigid_sampler(nxt, h, w)
        out[0, 4:5], moved = self.moved_logit(residual, occupancy, sampler)
        if nxt is not None:
            out[0, :4] = self._ego_flow(nxt, h, w)
        logit = np.float32(self.gain) * moved + out[0, 4:5]
        probability = (1.0 / (1.0 + np.exp(-logit)))[None].astype(np.float32)
        self.trace = HeadTrace(inputs, moved[0], sampler, probability[0, 0])
        return StepOutput(probability, out, [kept[None]])

    def moved_logit(
        self, residual: np.ndarray, occupancy: np.ndarray, sampler: Sampler | None
    ) -> tuple[np.ndarray, np.ndarray]:
        """The residual logit and the map the gain weighs ``(1, H, W)``, moved into the next
        frame by ``sampler`` (``None``: as they are): the residual's cells coming into view at
        the fill logit (EgoCompensated.to_next_frame)."""
        if sampler is None:
            return residual, occupancy
        both = sampler(np.concatenate([residual - self._fill, occupancy]))
        return both[0:1] + self._fill, np.clip(both[1:2], 0.0, 1.0)

    def residual(self, layers: list[tuple[np.ndarray, np.ndarray]], x: np.ndarray) -> np.ndarray:
        """``(1, H*W)``: the residual logit of ``layers`` on the features ``x`` ``(C, H*W)``."""
        return _forward(layers, x)[0]

    def _ego_flow(self, motion: np.ndarray, h: int, w: int) -> np.ndarray:
        """``(4, H, W)``: the platform's own backward and forward flow (the inner flow zero),
        the last one kept (a roll-out's every step has the same)."""
        key = (*np.asarray(motion, np.float64).reshape(3).tolist(), h, w)
        if key != self._flow_key:
            rows, cols = np.indices((h, w), dtype=np.float64)
            c1, r1 = rigid_positions(motion, h, w)
            c2, r2 = rigid_positions(motion, h, w, inverse=True)
            flow = np.stack([c1 - cols, r1 - rows, c2 - cols, r2 - rows]).astype(np.float32)
            self._flow_key, self._flow = key, flow
        return self._flow

    def _head(
        self, maps: np.ndarray, state: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, tuple[np.ndarray, ...]]:
        """:meth:`lidarflow.models.head.OccupancyHead.forward` on one frame: ``maps`` ``(C, H,
        W)``, ``state`` ``(S, H, W)`` -> the residual logit ``(1, H, W)``, the new state and
        each layer's input (:class:`HeadTrace`)."""
        c = self.config
        occupancy = maps[0:1]
        k = len(c.memory_decays)
        past = state[:k]
        shift = (0, 0)
        if c.constant_velocity_input:
            shift = best_rigid_shift(state[-1] > _OCCUPIED_ABOVE, occupancy[0] > _OCCUPIED_ABOVE)
            if c.shift_memories:
                past = _shifted(past, *shift)
        memory = self._decays * past + (1.0 - self._decays) * occupancy
        features, kept = [occupancy], [memory]
        if c.constant_velocity_input:
            if c.shift_memories:
                features.append(_shifted(np.concatenate([memory, occupancy]), *shift))
            else:
                features.extend((memory, _shifted(occupancy, *shift)))
            kept.append(occupancy)
        else:
            features.append(memory)
        if c.visibility_input:
            features.append(maps[1:2])
        if c.subcell_input:
            features.append(maps[2:4])
        x = np.concatenate(features).reshape(-1, occupancy[0].size)
        residual, inputs = _forward(self.layers, x)
        return residual.reshape(occupancy.shape), np.concatenate(kept), inputs


def _forward(
    layers: list[tuple[np.ndarray, np.ndarray]], x: np.ndarray
) -> tuple[np.ndarray, tuple[np.ndarray, ...]]:
    """The 1x1 layers on the features ``x`` ``(C, N)``, a ReLU between them: the output ``(1,
    N)`` and each layer's input."""
    inputs = [x]
    for weight, bias in layers[:-1]:
        x = _layer(weight, bias, x)
        np.maximum(x, 0.0, out=x)
        inputs.append(x)
    return _layer(*layers[-1], x), tuple(inputs)

