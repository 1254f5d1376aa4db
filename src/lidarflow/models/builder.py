"""The builder: a model assembled from its typed spec
(:class:`~lidarflow.models.config.ModelSpec`) or from the flat keyword form that ``model.json``
and training configs store."""

from __future__ import annotations

from typing import Any

from torch import nn

from lidarflow.errors import ModelError
from lidarflow.models.config import MODEL_NAMES, ModelSpec
from lidarflow.models.deeptracking import DeepTracking
from lidarflow.models.egomotion import EgoCompensated
from lidarflow.models.flow import FlowNetwork
from lidarflow.models.flownet import LidarFlowNet
from lidarflow.models.head import OccupancyHead
from lidarflow.models.recurrent import RecurrentMapModel
from lidarflow.models.sogmp import SOGMP

__all__ = ["build", "build_model", "count_parameters", "uses_ego_motion"]


def build(spec: ModelSpec) -> RecurrentMapModel:
    """The model ``spec`` describes, its blocks freshly initialised.

    Raises:
        ModelError: arguments the model does not take.
    """
    try:
        if spec.name == "deeptracking":
            model: RecurrentMapModel = DeepTracking(**spec.options)
        elif spec.name == "sogmp":
            model = SOGMP(**spec.options)
        else:
            head = None if spec.head is None else OccupancyHead(spec.head)
            flow = None if spec.flow is None else FlowNetwork(spec.flow)
            model = LidarFlowNet(flow, head)
    except (TypeError, ValueError) as err:
        raise ModelError(f"cannot build model {spec.name!r}: {err}") from err
    if not spec.ego_motion:
        return model
    return EgoCompensated(model, poses_optional=spec.poses_optional)


def build_model(name: str, **kwargs: Any) -> RecurrentMapModel:
    """Build the model called ``name`` (one of :data:`MODEL_NAMES`) from the flat keyword form
    (:meth:`ModelSpec.from_kwargs`): ``ego_motion`` wraps it in :class:`EgoCompensated`,
    ``poses_optional`` lets that run where a recording has no poses.

    Raises:
        ModelError: unknown name, arguments the model does not take, a removed option, or a
            decision key (the decision is the Predictor's, :mod:`lidarflow.predict.decision`).
    """
    if name not in MODEL_NAMES:
        raise ModelError(f"unknown model {name!r}: choose one of {', '.join(MODEL_NAMES)}")
    try:
        spec, decision = ModelSpec.from_kwargs(name, kwargs)
    except (TypeError, ValueError) as err:
        raise ModelError(f"cannot build model {name!r} with {kwargs}: {err}") from err
    if decision:
        raise ModelError(
            f"{', '.join(decision)}: the decision is the Predictor's configuration, not the "
            "model's (lidarflow.predict.decision.DecisionPolicy)"
        )
    return build(spec)


def uses_ego_motion(model: RecurrentMapModel) -> bool:
    """Whether ``model`` wants the sensor's motion with every step (:class:`EgoCompensated`)."""
    return model.capabilities.ego_motion


def count_parameters(model: nn.Module) -> int:
    """Number of trainable parameters of ``model``."""
    return sum(p.numel() for p in model.parameters() if p.requires_grad)
