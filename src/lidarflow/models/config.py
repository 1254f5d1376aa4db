"""Typed configuration of the models, and the capability record every model carries.

A :class:`ModelSpec` describes a model: its name, Table I's flow network (:class:`FlowConfig`),
the occupancy head (:class:`HeadConfig`) and the ego-motion wrapper's switches. ``model.json``
stores it flat (``model_kwargs``); :meth:`ModelSpec.from_kwargs` reads every such file, refusing
a removed option a model needs and handing back the decision keys older files kept.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

#: Logit given to cells that come into view in an occupancy model's rigidly warped output.
OCCUPANCY_FILL_LOGIT = math.log(0.02 / 0.98)

__all__ = [
    "DECISION_KEYS",
    "MAX_CHANNELS",
    "MODEL_NAMES",
    "REMOVED_OPTIONS",
    "Capabilities",
    "FlowConfig",
    "HeadConfig",
    "ModelSpec",
]

MODEL_NAMES: tuple[str, ...] = ("flownet", "deeptracking", "sogmp")
#: Keys older ``model_kwargs`` held that belong to the decision policy, not the model.
DECISION_KEYS = ("decision_offset", "online_decision")
#: Options measured without gain and removed, with the value a model built without them had.
REMOVED_OPTIONS: dict[str, Any] = {
    "memory_bias_correction": False,
    "decision_offset_free": None,
    "warp_input": False,
    "visibility_memories": False,
    "transition_memories": False,
    "conv0_activation": "relu",
    "in_channels": 2,
}
#: The most channels any layer may have (SOGMP's 128 hidden channels times 8): a file asking
#: for more is damaged, not a model.
MAX_CHANNELS = 1024
_MAX_COUNT = 32  # dilations, memory decays, residual layers, frames of SOGMP's window
#: The sizes a flat description may give, each a whole number in ``[low, high]`` (every entry
#: of ``dilations``).
_SIZES: dict[str, tuple[int, int]] = {
    "hidden_channels": (1, MAX_CHANNELS),
    "head_hidden_channels": (0, MAX_CHANNELS),
    "lstm_channels": (1, MAX_CHANNELS),
    "residual_channels": (1, MAX_CHANNELS),
    "latent_channels": (1, MAX_CHANNELS),
    "kernel_size": (1, 15),
    "dilations": (1, 64),
    "window": (1, _MAX_COUNT),
    "residual_layers": (0, _MAX_COUNT),
}
_LISTS = ("dilations", "memory_decays")


def _check_numbers(kwargs: dict[str, Any]) -> None:
    """Raise ``ValueError`` naming the first argument of a flat description that is a number
    but not finite, a size out of :data:`_SIZES`' bounds, or a list too long."""
    for key, value in kwargs.items():
        items = list(value) if isinstance(value, (list, tuple)) else [value]
        numbers = [v for v in items if isinstance(v, (int, float)) and not isinstance(v, bool)]
        if not all(math.isfinite(v) for v in numbers if isinstance(v, float)):
            raise ValueError(f"{key} must be finite, got {value}")
        if key in _LISTS and len(items) > _MAX_COUNT:
            raise ValueError(f"{key} may have at most {_MAX_COUNT} entries, got {len(items)}")
        if key in _SIZES:
            low, high = _SIZES[key]
            if len(numbers) < len(items) or not all(
                v == int(v) and low <= v <= high for v in numbers
            ):
                raise ValueError(f"{key} must be a whole number in [{low}, {high}], got {value}")


# The head of each cell's own past is the only head left: a 1x1 kernel, no GRU features.
_HEAD_SHAPE = {"head_kernel_size": 1, "head_flow_features": False}
# The flat keys of the flow network (``flow_network: false`` stores a model without one), and
# the FlowConfig fields they hold.
_FLOW_KEYS = ("hidden_channels", "dilations", "kernel_size", "zero_init_flow")
_FLOW_FIELDS = ("hidden_channels", "dilations", "kernel_size", "zero_init")


@dataclass(frozen=True)
class Capabilities:
    """What a model takes and gives, read by the streaming engine instead of probing:
    ``input_channels`` per frame (2: ``(O, V)``; 4 with the sub-cell maps), ``out_channels``
    per step, ``flow`` (its output's ``B_col, B_row, F_col, F_row`` estimate what moves; a
    model without a flow network keeps those channels but says ``False``), ``occupancy_head``
    (its probability is a calibrated ``sigmoid`` of a logit), ``ego_motion`` (``step`` takes
    the sensor's motion) and ``poses_optional`` (it may run without poses)."""

    input_channels: int = 2
    out_channels: int = 4
    flow: bool = True
    occupancy_head: bool = False
    ego_motion: bool = False
    poses_optional: bool = False


@dataclass(frozen=True)
class FlowConfig:
    """Table I's flow network: ``conv0`` 3x3 to ``hidden_channels`` (ReLU), one ConvGRU per
    dilation, ``conv_flow`` to 4 channels; ``zero_init`` starts the flow head at zero (the
    untrained net is copy-last)."""

    hidden_channels: int = 16
    dilations: tuple[int, ...] = (1, 2, 4)
    kernel_size: int = 3
    zero_init: bool = True

    def __post_init__(self) -> None:
        _check_numbers(
            {
                "hidden_channels": self.hidden_channels,
                "dilations": self.dilations,
                "kernel_size": self.kernel_size,
            }
        )
        if self.hidden_channels < 1 or not self.dilations or self.kernel_size % 2 == 0:
            raise ValueError(
                "the flow network needs hidden_channels >= 1, at least one dilation and an odd "
                f"kernel_size, got {self.hidden_channels}, {self.dilations}, {self.kernel_size}"
            )


@dataclass(frozen=True)
class HeadConfig:
    """The occupancy head (:mod:`lidarflow.models.head`, which describes each option)."""

    memory_decays: tuple[float, ...] = (0.5, 0.8)
    constant_velocity_input: bool = False
    shift_memories: bool = False
    hidden_channels: int = 0
    visibility_input: bool = False
    subcell_input: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "memory_decays", tuple(float(d) for d in self.memory_decays))
        _check_numbers(
            {"head_hidden_channels": self.hidden_channels, "memory_decays": self.memory_decays}
        )
        if not all(0.0 <= d < 1.0 for d in self.memory_decays):
            raise ValueError(f"memory_decays must be in [0, 1), got {self.memory_decays}")
        if self.shift_memories and not self.constant_velocity_input:
            raise ValueError("shift_memories needs constant_velocity_input (it finds the shift)")
        if self.hidden_channels < 0:
            raise ValueError(f"head hidden_channels must be >= 0, got {self.hidden_channels}")


@dataclass(frozen=True)
class ModelSpec:
    """A whole model: ``name`` (one of :data:`MODEL_NAMES`); for ``flownet`` its ``flow``
    (``None``: the head alone) and ``head``; for ``deeptracking`` and ``sogmp`` the arguments of
    their class as ``options``; ``ego_motion`` wraps it in
    :class:`~lidarflow.models.egomotion.EgoCompensated`, ``poses_optional`` lets that run
    without poses."""

    name: str = "flownet"
    flow: FlowConfig | None = field(default_factory=FlowConfig)
    head: HeadConfig | None = None
    ego_motion: bool = False
    poses_optional: bool = False
    options: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        _check_numbers(self.options)
        if self.name == "flownet" and self.flow is None and self.head is None:
            raise ValueError("a flownet without a flow network needs an occupancy head")
        if self.name not in MODEL_NAMES:
            raise ValueError(f"unknown model {self.name!r}: choose one of {', '.join(MODEL_NAMES)}")
        if self.poses_optional and not self.ego_motion:
            raise ValueError("poses_optional needs ego_motion (it says when poses may be missing)")
        if self.name != "flownet" and self.head is not None:
            raise ValueError("the occupancy head belongs to flownet")

    @classmethod
    def from_kwargs(
        cls, name: str, kwargs: dict[str, Any], stored: bool = False
    ) -> tuple[ModelSpec, dict[str, Any]]:
        """The spec of a model described flat (``model.json``'s ``model_kwargs``, a training
        config's ``model.kwargs``), and the :data:`DECISION_KEYS` found among them. ``stored``:
        from a file, where a head without ``head_kernel_size`` 1 and ``head_flow_features``
        false is the removed 3x3 head. Raises ``ValueError`` naming an unknown argument, a
        removed option the model needs, or a number not finite or beyond its bounds."""
        kwargs = dict(kwargs)
        _check_numbers(kwargs)
        decision = {k: kwargs.pop(k) for k in DECISION_KEYS if k in kwargs}
        ego = bool(kwargs.pop("ego_motion", False))
        optional = bool(kwargs.pop("poses_optional", False))
        for option, default in REMOVED_OPTIONS.items():
            if option in kwargs and kwargs.pop(option) != default:
                raise ValueError(
                    f"{option} was measured without gain and removed; this model needs it "
                    "(train it again, or use lidarflow at commit a4a22da for it)"
                )
        if name != "flownet":
            return cls(name, ego_motion=ego, poses_optional=optional, options=kwargs), decision
        flow: FlowConfig | None = None
        if kwargs.pop("flow_network", True):
            flow = FlowConfig(
                hidden_channels=int(kwargs.pop("hidden_channels", 16)),
                dilations=tuple(kwargs.pop("dilations", (1, 2, 4))),
                kernel_size=int(kwargs.pop("kernel_size", 3)),
                zero_init=bool(kwargs.pop("zero_init_flow", True)),
            )
        elif given := [k for k in _FLOW_KEYS if k in kwargs]:
            raise ValueError(f"{', '.join(given)}: options of a flow network, and flow_network "
                             "is false")
        head = None
        if kwargs.pop("occupancy_head", False):
            for key, value in _HEAD_SHAPE.items():
                if kwargs.pop(key, None if stored else value) != value:
                    raise ValueError(
                        "a head with a 3x3 kernel or the GRUs' features was measured without "
                        "gain and removed; this model has one (train it again with the head "
                        "recipe)"
                    )
            head = HeadConfig(
                memory_decays=tuple(kwargs.pop("memory_decays", (0.5, 0.8))),
                constant_velocity_input=bool(kwargs.pop("constant_velocity_input", False)),
                shift_memories=bool(kwargs.pop("shift_memories", False)),
                hidden_channels=int(kwargs.pop("head_hidden_channels", 0)),
                visibility_input=bool(kwargs.pop("visibility_input", False)),
                subcell_input=bool(kwargs.pop("subcell_input", False)),
            )
        if kwargs:
            raise ValueError(f"unexpected model arguments: {', '.join(sorted(kwargs))}")
        return cls(name, flow, head, ego, optional), decision

    def to_kwargs(self) -> dict[str, Any]:
        """The flat form :meth:`from_kwargs` reads (what ``model.json`` stores)."""
        out: dict[str, Any] = dict(self.options)
        if self.name == "flownet" and self.flow is None:
            out["flow_network"] = False
        elif self.name == "flownet":
            default = FlowConfig()
            for key, name in zip(_FLOW_KEYS, _FLOW_FIELDS, strict=True):
                value = getattr(self.flow, name)
                if value != getattr(default, name):
                    out[key] = list(value) if isinstance(value, tuple) else value
        if self.head is not None:
            head = asdict(self.head)
            head["memory_decays"] = list(self.head.memory_decays)
            head["head_hidden_channels"] = head.pop("hidden_channels")
            out.update({"occupancy_head": True, **head, **_HEAD_SHAPE})
        if self.ego_motion:
            out["ego_motion"] = True
        if self.poses_optional:
            out["poses_optional"] = True
        return out
