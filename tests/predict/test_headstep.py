"""The head-only step in NumPy against PyTorch's, and which models it takes (issue 46)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from lidarflow.models import ModelSpec, build
from lidarflow.models.config import HeadConfig
from lidarflow.predict.backends import TorchBackend, load_backend
from lidarflow.predict.headstep import HeadStepBackend, supports
from lidarflow.predict.step import StepInputs

HEADS = {
    "memories": {"memory_decays": [0.5, 0.9]},
    "constant_velocity": {"memory_decays": [0.5], "constant_velocity_input": True},
    "hidden_visibility": {"head_hidden_channels": 5, "visibility_input": True},
    "bundled_like": {
        "memory_decays": [0.5, 0.8, 0.95],
        "constant_velocity_input": True,
        "shift_memories": True,
        "visibility_input": True,
        "subcell_input": True,
        "head_hidden_channels": 6,
    },
}


def head_model(kwargs: dict, ego: bool, seed: int = 0):
    torch.manual_seed(seed)
    options = {"flow_network": False, "occupancy_head": True, "ego_motion": ego, **kwargs}
    spec, _ = ModelSpec.from_kwargs("flownet", options)
    net = build(spec).eval()
    with torch.no_grad():  # random weights everywhere, so that every input shapes the output
        for p in net.parameters():
            p.copy_(torch.randn_like(p) * 0.5)
    return net


def frames(rng: np.random.Generator, channels: int, n: int = 12) -> list[np.ndarray]:
    """A blob drifting a cell a frame, then fractional maps (a roll-out's fed-back ones)."""
    out = []
    for t in range(n):
        maps = np.zeros((1, channels, 24, 20), np.float32)
        maps[0, 0, 5 + t // 2 : 9 + t // 2, 6 + t % 3 : 10 + t % 3] = 1.0
        maps[0, 0] = np.maximum(maps[0, 0], rng.random((24, 20)) > 0.95)
        if t >= n - 3:
            maps[0, 0] *= rng.random((24, 20)).astype(np.float32)
        maps[0, 1] = rng.random((24, 20)) > 0.3
        if channels == 4:
            maps[0, 2:] = rng.random((2, 24, 20))
        out.append(maps)
    return out


@pytest.mark.parametrize("ego", [True, False], ids=["ego", "no_ego"])
@pytest.mark.parametrize("kwargs", list(HEADS.values()), ids=list(HEADS))
def test_the_numpy_step_is_pytorchs(kwargs, ego) -> None:
    net = head_model(kwargs, ego)
    assert supports(net)
    fast, reference = HeadStepBackend(net), TorchBackend(net)
    rng = np.random.default_rng(1)
    a, b = fast.init_state(24, 20), reference.init_state(24, 20)
    motions = [None, np.array([0.5, -0.3, 0.02], np.float32), np.array([1.0, 0.0, -0.05])]
    for t, maps in enumerate(frames(rng, net.input_channels)):
        motion = motions[t % 3]
        guess = None if t % 4 else np.array([0.25, 0.1, 0.01], np.float32)
        pa, oa, a = fast.run(StepInputs(maps, motion, guess), a)
        pb, ob, b = reference.run(StepInputs(maps, motion, guess), b)
        np.testing.assert_allclose(pa, pb, atol=1e-5)
        np.testing.assert_allclose(oa, ob, atol=1e-4)  # flow and logit, cells and logits
        np.testing.assert_allclose(a[0], b[0].numpy(), atol=1e-5)
    assert fast.gain == pytest.approx(reference.gain)
    assert fast.capabilities == reference.capabilities


def test_the_bundled_model_runs_on_the_numpy_step_on_the_cpu() -> None:
    backend, card = load_backend(None)
    assert isinstance(backend, HeadStepBackend)
    assert card["decision"]["online"]


def test_models_it_does_not_know_stay_on_pytorch() -> None:
    flow_model = build(ModelSpec.from_kwargs("flownet", {"occupancy_head": True})[0])
    assert not supports(flow_model)  # a flow network
    assert not supports(build(ModelSpec(name="deeptracking", flow=None)))
    half = head_model(HEADS["memories"], ego=True).double()
    assert not supports(half)  # not float32

    # A head config with an input this step does not compute (one added later).
    @dataclasses.dataclass(frozen=True)
    class Wider(HeadConfig):
        flow_features: bool = True

    net = head_model(HEADS["memories"], ego=True)
    net.inner.head.config = Wider(memory_decays=(0.5, 0.9))
    assert not supports(net)
    with pytest.raises(ValueError, match="head-only"):
        HeadStepBackend(net)


def test_the_bundled_head_read_without_pytorch_is_the_one_pytorch_loads() -> None:
    """read_head takes the weights from the files alone (the core install's way to learn): the
    same arrays, gain and capabilities as from the PyTorch model, so the same step."""
    import json

    from lidarflow.models.presets import bundled_model_dir, resolve_model
    from lidarflow.models.weights import read_safetensors
    from lidarflow.predict.headstep import read_head

    folder = bundled_model_dir()
    card = json.loads((folder / "model.json").read_text())
    head = read_head(card, folder / "model.safetensors")
    assert head is not None
    numpy_only, reference = HeadStepBackend(head), HeadStepBackend(resolve_model(None)[0])
    for (a, b), (c, d) in zip(numpy_only.layers, reference.layers, strict=True):
        np.testing.assert_array_equal(a, c)
        np.testing.assert_array_equal(b, d)
    assert numpy_only.gain == reference.gain
    assert numpy_only.capabilities == reference.capabilities
    from safetensors.numpy import load_file

    weights = folder / "model.safetensors"
    ours, theirs = read_safetensors(weights), load_file(weights)
    assert ours.keys() == theirs.keys()
    assert all(np.array_equal(ours[k], theirs[k]) for k in ours)
    flow_card = {"model": "flownet", "model_kwargs": {"flow_network": True}}
    assert read_head(flow_card, folder / "model.safetensors") is None  # not a head-only model
