"""Models: LiDAR-FlowNet (the flow network of Table I, an occupancy head, the ego-motion
wrapper), the DeepTracking and SOGMP peers, their recurrent cells, and the builder.

Interface (train, evaluate and predict depend on it; details in
:mod:`lidarflow.models.recurrent`): every model has ``capabilities``, ``init_state``, ``step``,
``forward`` and ``predict_next``. :func:`build` assembles one from a typed
:class:`~lidarflow.models.config.ModelSpec`; :func:`build_model` from the flat keyword form
that ``model.json`` and training configs store. Pretrained weights: :mod:`lidarflow.models.presets`
(``lidar_flownet(weights=...)``).

Importing this package needs no PyTorch (the core install runs exported models on ONNX
Runtime, :mod:`lidarflow.predict.backends`): the configuration types load at once, the blocks
and the builder, which need PyTorch, on first use.
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
    "SOGMP",
    "Capabilities",
    "ConvGRUCell",
    "DeepTracking",
    "EgoCompensated",
    "FlowConfig",
    "FlowNetwork",
    "HeadConfig",
    "LidarFlowNet",
    "ModelSpec",
    "OccupancyHead",
    "RecurrentMapModel",
    "build",
    "build_model",
    "count_parameters",
    "uses_ego_motion",
]
