"""LiDAR-FlowNet without its flow network (issue 36): the occupancy head alone."""

from __future__ import annotations

import json

import pytest
import torch

from lidarflow.errors import ModelError
from lidarflow.models import LidarFlowNet, ModelSpec, build, build_model, count_parameters
from lidarflow.models.config import FlowConfig
from lidarflow.models.head import OccupancyHead
from lidarflow.models.presets import resolve_model
from tests.conftest import make_model_dir
from tests.head_only_pair import HEAD, head_only, zeroed_twin


def test_the_step_is_the_head_alone_with_four_zero_flow_channels():
    model = head_only()
    state = model.init_state(2, 12, 10)
    assert model.state_channels() == (OccupancyHead(HEAD).state_channels,) == (3,)
    maps = (torch.rand(2, 4, 12, 10) > 0.7).float()
    out, state = model.step(maps, state)
    assert out.shape == (2, 5, 12, 10) and len(state) == 1 and state[0].shape == (2, 3, 12, 10)
    assert not out[:, :4].any()
    residual, memory = model.head(maps, model.init_state(2, 12, 10)[0])
    torch.testing.assert_close(out[:, 4:], residual)
    torch.testing.assert_close(state[0], memory)
    # No warp: the head weighs the map itself.
    logit = model.next_logit(maps, out)
    torch.testing.assert_close(logit, model.head.gain * maps[:, :1] + residual)
    caps = model.capabilities
    assert (caps.flow, caps.occupancy_head, caps.out_channels, caps.input_channels) == (
        False, True, 5, 4,
    )  # fmt: skip


def test_its_parameters_are_the_heads_alone():
    model = head_only()
    assert count_parameters(model) == count_parameters(OccupancyHead(HEAD))
    assert all(name.startswith("head.") for name, _ in model.named_parameters())
    with_flow = build(ModelSpec("flownet", FlowConfig(), HEAD))
    assert count_parameters(with_flow) == count_parameters(model) + 42500


@pytest.mark.parametrize("ego", [False, True], ids=["plain", "ego_motion"])
def test_it_predicts_what_the_same_head_on_a_zeroed_flow_predicts(ego):
    model = head_only(ego=ego, seed=1)
    twin = zeroed_twin(model)
    torch.manual_seed(2)
    seq = (torch.rand(1, 6, 4, 16, 14) > 0.7).float()
    motions = torch.tensor([[0.6, -0.3, 0.05]]).repeat(1, 6, 1) if ego else None
    args = (None, motions) if ego else ()
    with torch.no_grad():
        out, _ = model(seq, *args)
        ref, _ = twin(seq, *args)
        torch.testing.assert_close(out, ref, atol=1e-5, rtol=1e-5)
        if ego:  # the wrapper's flow: the platform's own, which moves the map
            assert out[:, :, :4].abs().amax() > 0.5
        for t in range(6):
            p, q = model.predict_next(seq[:, t], out[:, t]), twin.predict_next(seq[:, t], ref[:, t])
            torch.testing.assert_close(p, q, atol=1e-5, rtol=1e-5)


def test_without_a_head_it_is_refused_in_one_line():
    with pytest.raises(ModelError, match="without a flow network needs an occupancy head"):
        build_model("flownet", flow_network=False)
    with pytest.raises(ValueError, match="needs an occupancy head"):
        LidarFlowNet(None, None)
    with pytest.raises(ValueError, match="needs an occupancy head"):
        ModelSpec("flownet", None, None)
    with pytest.raises(ModelError, match="hidden_channels: options of a flow network"):
        build_model("flownet", flow_network=False, occupancy_head=True, hidden_channels=8)


def test_it_round_trips_through_model_json(tmp_path):
    kwargs = {"flow_network": False, "occupancy_head": True, "ego_motion": True}
    folder = make_model_dir(tmp_path / "run", **kwargs)
    stored = json.loads((folder / "model.json").read_text())["model_kwargs"]
    assert stored["flow_network"] is False and "hidden_channels" not in stored
    model, _ = resolve_model(folder)
    assert not model.capabilities.flow and model.capabilities.ego_motion
    spec, _ = ModelSpec.from_kwargs("flownet", stored, stored=True)
    assert spec.flow is None and spec.to_kwargs() == stored
    assert ModelSpec.from_kwargs("flownet", spec.to_kwargs())[0] == spec
