"""Models: LiDAR-FlowNet, the DeepTracking baseline, their ConvGRU cell, and the builder.

Interface (train, evaluate and predict depend on it; details in
:mod:`lidarflow.models.recurrent`): every model has ``out_channels``, ``init_state``, ``step``,
``forward`` and ``predict_next``. ``build_model(name, **kwargs)`` builds one by name;
``ego_motion=True`` wraps it in :class:`EgoCompensated` (its ``step`` then also takes the sensor's
motion, see :mod:`lidarflow.models.egomotion`); ``poses_optional=True`` with it lets the model run
on recordings that have no poses at all (evaluate and predict then match the motion from the
scans).
"""

from __future__ import annotations

from collections.abc import Callable

from torch import nn

from lidarflow.errors import ModelError
from lidarflow.models.convgru import ConvGRUCell
from lidarflow.models.deeptracking import DeepTracking, deeptracking
from lidarflow.models.egomotion import EgoCompensated
from lidarflow.models.flownet import LidarFlowNet, lidar_flownet
from lidarflow.models.recurrent import RecurrentMapModel

_BUILDERS: dict[str, Callable[..., RecurrentMapModel]] = {
    "flownet": LidarFlowNet,
    "deeptracking": DeepTracking,
}
MODEL_NAMES: tuple[str, ...] = tuple(_BUILDERS)


def build_model(name: str, **kwargs: object) -> RecurrentMapModel:
    """Build the model called ``name`` (one of :data:`MODEL_NAMES`); ``kwargs`` go to its class,
    except ``ego_motion`` (default False): True wraps the model in :class:`EgoCompensated`, and
    ``poses_optional`` (default False, only with ``ego_motion``): True marks it as one that may
    run where a recording has no poses (on the motion matched from the scans, or uncompensated),
    rather than being refused there.

    Raises:
        ModelError: unknown name, or arguments the model does not take.
    """
    try:
        builder = _BUILDERS[name]
    except KeyError as err:
        raise ModelError(f"unknown model {name!r}: choose one of {', '.join(MODEL_NAMES)}") from err
    ego_motion = bool(kwargs.pop("ego_motion", False))
    poses_optional = bool(kwargs.pop("poses_optional", False))
    if poses_optional and not ego_motion:
        raise ModelError("poses_optional needs ego_motion=True (it says when poses may be missing)")
    try:
        model = builder(**kwargs)
    except (TypeError, ValueError) as err:
        raise ModelError(f"cannot build model {name!r} with {kwargs}: {err}") from err
    if not ego_motion:
        return model
    try:
        return EgoCompensated(model, poses_optional=poses_optional)
    except ValueError as err:
        raise ModelError(f"cannot compensate ego motion for model {name!r}: {err}") from err


def uses_ego_motion(model: object) -> bool:
    """Whether ``model`` wants the sensor's motion with every step (:class:`EgoCompensated`)."""
    return bool(getattr(model, "ego_motion", False))


def count_parameters(model: nn.Module) -> int:
    """Number of trainable parameters of ``model``."""
    return sum(p.numel() for p in model.parameters() if p.requires_grad)


__all__ = [
    "MODEL_NAMES",
    "ConvGRUCell",
    "DeepTracking",
    "EgoCompensated",
    "LidarFlowNet",
    "RecurrentMapModel",
    "build_model",
    "count_parameters",
    "deeptracking",
    "lidar_flownet",
    "uses_ego_motion",
]
