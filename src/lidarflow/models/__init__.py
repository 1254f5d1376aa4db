"""Models: LiDAR-FlowNet (the flow network of Table I, an occupancy head, the ego-motion
wrapper), the DeepTracking and SOGMP peers, their recurrent cells, and the builder.

Every model offers the interface of :mod:`lidarflow.models.recurrent`. :func:`build` assembles
one from a :class:`~lidarflow.models.config.ModelSpec`, :func:`build_model` from the flat form
``model.json`` stores; pretrained weights: :mod:`lidarflow.models.presets`.

Importing this package needs no PyTorch (the core install runs exported models on ONNX
Runtime): the configuration types load at once, the blocks and the builder on first use.
"""

from __future__ import annotations

import importlib
from typing import Any

from lidarflow.models.config import (
    DECISION_KEYS,
    MODEL_NAMES,
    Capabilities,
    FlowConfig,
    HeadConfig,
    ModelSpec,
)

#: The names that need PyTorch, and the module each comes from.
_TORCH_NAMES = {
    "ConvGRUCell": "convgru",
    "DeepTracking": "deeptracking",
    "EgoCompensated": "egomotion",
    "FlowNetwork": "flow",
    "LidarFlowNet": "flownet",
    "OccupancyHead": "head",
    "RecurrentMapModel": "recurrent",
    "SOGMP": "sogmp",
    "build": "builder",
    "build_model": "builder",
    "count_parameters": "builder",
    "uses_ego_motion": "builder",
}


def __getattr__(name: str) -> Any:
    module = _TORCH_NAMES.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{module}"), name)


__all__ = [
    "DECISION_KEYS",
    "MODEL_NAMES",
    "Capabilities",
    "FlowConfig",
    "HeadConfig",
    "ModelSpec",
    *_TORCH_NAMES,
]
