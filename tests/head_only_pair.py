"""A LiDAR-FlowNet without its flow network and the same head on a flow network whose flow head
is zero: the two must predict alike (the flow-free model is that model, minus the ConvGRUs)."""

from __future__ import annotations

import json
from pathlib import Path

import torch

from lidarflow.models import ModelSpec, build
from lidarflow.models.config import FlowConfig, HeadConfig

#: The ``head`` recipe's head (every input the head takes), kept small for speed.
HEAD = HeadConfig(
    memory_decays=(0.5, 0.95),
    constant_velocity_input=True,
    shift_memories=True,
    hidden_channels=4,
    visibility_input=True,
    subcell_input=True,
)


def head_only(head: HeadConfig = HEAD, ego: bool = False, seed: int = 0) -> torch.nn.Module:
    """A flow-free model whose head has random (not copy-last) weights."""
    torch.manual_seed(seed)
    model = build(ModelSpec("flownet", None, head, ego_motion=ego, poses_optional=ego))
    with torch.no_grad():
        for name, p in model.named_parameters():
            p.copy_(torch.randn_like(p) * 0.5 if name.endswith("weight") else p)
    return model.eval()


def zeroed_twin(model: torch.nn.Module) -> torch.nn.Module:
    """``model``'s head on a random flow network whose flow head is zero."""
    ego = model.capabilities.ego_motion
    inner = model.inner if ego else model
    spec = ModelSpec("flownet", FlowConfig(), inner.head.config, ego_motion=ego, poses_optional=ego)
    twin = build(spec)
    with torch.no_grad():
        for name, p in twin.named_parameters():
            if ".conv_flow." not in name:
                p.copy_(torch.randn_like(p))  # the GRUs compute something: nothing comes of it
    twin.load_state_dict({**twin.state_dict(), **model.state_dict()})
    flow = twin.inner.flow if ego else twin.flow
    assert not flow.conv_flow.weight.any() and not flow.conv_flow.bias.any()
    return twin.eval()


def save_model_dir(model: torch.nn.Module, folder: Path, decision: dict | None = None) -> Path:
    """A run folder (``model.json``, ``model.safetensors``) holding ``model`` as it is."""
    from safetensors.torch import save_file

    ego = model.capabilities.ego_motion
    inner = model.inner if ego else model
    flow = None if inner.flow is None else FlowConfig()
    spec = ModelSpec("flownet", flow, inner.head.config, ego_motion=ego, poses_optional=ego)
    folder.mkdir(parents=True, exist_ok=True)
    weights = {k: v.contiguous() for k, v in model.state_dict().items()}
    save_file(weights, folder / "model.safetensors")
    card = {"model": "flownet", "model_kwargs": spec.to_kwargs()}
    card["decision"] = decision or {"offset": 0.0, "online": False}
    (folder / "model.json").write_text(json.dumps(card))
    return folder
