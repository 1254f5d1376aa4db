"""What a run starts from: the model's initial weights (``model.init``) and its optimizer. The
occupancy head, the part a run may add to trained weights, has its own learning rate
(``optim.head_lr_scale``) and may be missing or of another shape in ``model.init``'s weights.
"""

from __future__ import annotations

from typing import Any

import torch

from lidarflow.errors import ModelError, TrainError
from lidarflow.models import uses_ego_motion
from lidarflow.train.config import TrainConfig

__all__ = ["is_head", "load_init", "make_optimizer", "parameter_groups"]


def is_head(parameter_name: str) -> bool:
    """Whether a parameter belongs to the occupancy head block (its own learning rate, may be
    new): ``head.``, inside the ego-motion wrapper ``inner.head.``."""
    return parameter_name.removeprefix("inner.").startswith("head.")


def _unwrapped(model: torch.nn.Module) -> torch.nn.Module:
    return model.inner if uses_ego_motion(model) else model  # type: ignore[return-value]


def load_init(model: torch.nn.Module, source: str) -> bool:
    """Copy the weights of ``source`` (run folder, weights file or ``bundled``) into ``model``;
    returns whether the head was left new.

    Weights without a head, or with a head of other inputs, start a model with one: the flow
    is copied and the head keeps its copy-last initialisation. A model without a flow network
    takes the head alone."""
    from lidarflow.models.presets import resolve_model

    try:
        init, _ = resolve_model(source)
        # Ego-motion compensation adds no weight, only the wrapper's "inner." prefix: a model
        # with it starts from one without and the other way round.
        model, init = _unwrapped(model), _unwrapped(init)
        own, weights = model.state_dict(), init.state_dict()
        if any(n.startswith("flow.") for n in own) and not any(
            n.startswith("flow.") for n in weights
        ):
            # The bundled model is the head alone: a flow model cannot start from it.
            raise TrainError(
                f"model.init {source}: it has no flow network to start this model's from; pass "
                "--init RUN of a flow model (--recipe blurred or supervised_flow), or train "
                "--recipe head_only"
            )
        if not any(n.startswith("flow.") for n in own):  # no flow network: its head alone
            weights = {n: v for n, v in weights.items() if not n.startswith("flow.")}
        if any(is_head(n) and n in own and own[n].shape != v.shape for n, v in weights.items()):
            # A head of other inputs: none of it fits, the new head starts afresh.
            weights = {n: v for n, v in weights.items() if not is_head(n)}
        missing = set(model.state_dict()) - set(weights)
        head_only = bool(missing) and all(is_head(name) for name in missing)
        model.load_state_dict(weights, strict=not head_only)
    except (ModelError, RuntimeError) as err:
        first = str(err).strip().splitlines()[0]
        raise TrainError(f"model.init {source}: cannot start from these weights ({first})") from err
    return head_only


def parameter_groups(model: torch.nn.Module, config: TrainConfig) -> list[dict[str, Any]]:
    """The optimizer's groups: the network besides the head, then the head at its scaled rate
    (each where there is one)."""
    head, rest = [], []
    for name, p in model.named_parameters():
        (head if is_head(name) else rest).append(p)
    groups: list[dict[str, Any]] = [{"params": rest}] if rest else []
    if head:
        groups.append({"params": head, "lr": config.optim.lr * config.optim.head_lr_scale})
    return groups


def make_optimizer(config: TrainConfig, model: torch.nn.Module) -> torch.optim.Optimizer:
    """``config.optim``'s optimizer over :func:`parameter_groups` of ``model``."""
    o = config.optim
    params = parameter_groups(model, config)
    if o.name == "sgd":
        return torch.optim.SGD(params, lr=o.lr, momentum=o.momentum, weight_decay=o.weight_decay)
    cls = torch.optim.AdamW if o.name == "adamw" else torch.optim.Adam
    return cls(params, lr=o.lr, weight_decay=o.weight_decay)
