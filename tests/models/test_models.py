"""Tests of LiDAR-FlowNet, the DeepTracking baseline and the common model interface."""

from __future__ import annotations

import pytest
import torch

from lidarflow.errors import ModelError
from lidarflow.models import (
    MODEL_NAMES,
    SOGMP,
    DeepTracking,
    LidarFlowNet,
    build_model,
    count_parameters,
)
from lidarflow.scan import takes_subcell

PAPER_PARAMETERS = 42_500  # Table I, "about 42.5 K"


def _seq(b=2, t=4, h=12, w=10, seed=0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    occ = (torch.rand(b, t, 1, h, w, generator=g) > 0.8).float()
    vis = torch.maximum(occ, (torch.rand(b, t, 1, h, w, generator=g) > 0.3).float())
    return torch.cat([occ, vis], dim=2)


def _randomise_head(model: torch.nn.Module) -> None:
    torch.manual_seed(5)
    head = model.flow.conv_flow if isinstance(model, LidarFlowNet) else model.decoder
    if isinstance(model, SOGMP):
        head = model.decoder.net[-1]
    with torch.no_grad():
        head.weight.normal_(0, 0.5)
        head.bias.normal_(0, 0.5)


def test_model_names_and_builder():
    assert set(MODEL_NAMES) == {"flownet", "deeptracking", "sogmp"}
    assert isinstance(build_model("flownet"), LidarFlowNet)
    assert isinstance(build_model("deeptracking"), DeepTracking)
    assert isinstance(build_model("sogmp"), SOGMP)
    assert build_model("flownet", hidden_channels=8).flow.state_channels() == (8, 8, 8)
    with pytest.raises(ModelError, match="unknown model 'raft'"):
        build_model("raft")
    with pytest.raises(ModelError, match="cannot build"):
        build_model("flownet", nonsense=1)
    # Options measured without gain are gone, and a file that needs one says so.
    with pytest.raises(ModelError, match="conv0_activation was measured without gain"):
        build_model("flownet", conv0_activation="none")
    # The decision is the Predictor's, not the model's.
    with pytest.raises(ModelError, match="decision_offset: the decision is the Predictor's"):
        build_model("flownet", occupancy_head=True, decision_offset=0.5)


def test_flownet_has_the_papers_parameter_count():
    net = build_model("flownet")
    assert count_parameters(net) == PAPER_PARAMETERS
    per_layer = {
        name: sum(p.numel() for p in m.parameters()) for name, m in net.flow.named_children()
    }
    assert per_layer["conv0"] == 2 * 16 * 9 + 16
    assert per_layer["conv_flow"] == 16 * 4 * 9 + 4


def test_deeptracking_budget_is_close_to_flownets():
    n = count_parameters(build_model("deeptracking"))
    assert 40_000 <= n <= 60_000


def test_count_parameters_ignores_frozen_ones():
    net = build_model("flownet")
    net.flow.conv0.requires_grad_(False)
    assert count_parameters(net) == PAPER_PARAMETERS - (2 * 16 * 9 + 16)


@pytest.mark.parametrize(("name", "channels"), [("flownet", 4), ("deeptracking", 1)])
def test_shapes_and_state_of_both_models(name, channels):
    model = build_model(name)
    assert model.out_channels == channels
    state = model.init_state(3, 13, 7)
    assert len(state) == 3
    assert all(s.shape == (3, 16, 13, 7) and s.abs().sum() == 0 for s in state)
    assert state[0].dtype == torch.float32
    assert model.init_state(1, 5, 5, dtype=torch.float64)[0].dtype == torch.float64
    out, new_state = model.step(_seq(3, 1, 13, 7)[:, 0], state)
    assert out.shape == (3, channels, 13, 7)
    assert [s.shape for s in new_state] == [s.shape for s in state]
    seq_out, _ = model(_seq(3, 5, 13, 7))
    assert seq_out.shape == (3, 5, channels, 13, 7)
    p = model.predict_next(_seq(3, 1, 13, 7)[:, 0], out)
    assert p.shape == (3, 1, 13, 7)
    assert p.min() >= 0 and p.max() <= 1


@pytest.mark.parametrize("name", MODEL_NAMES)
def test_step_over_time_equals_forward_and_forward_resumes(name):
    model = build_model(name).eval()  # SOGMP draws its latent in training mode
    _randomise_head(model)
    seq = _seq(2, 6)
    expected, expected_state = model(seq)
    state = model.init_state(2, 12, 10)
    for t in range(6):
        out, state = model.step(seq[:, t], state)
        torch.testing.assert_close(out, expected[:, t])
    for a, b in zip(state, expected_state, strict=True):
        torch.testing.assert_close(a, b)
    # split in two calls, carrying the state, gives the same outputs
    first, mid_state = model(seq[:, :2])
    second, _ = model(seq[:, 2:], mid_state)
    torch.testing.assert_close(torch.cat([first, second], dim=1), expected)


@pytest.mark.parametrize("name", MODEL_NAMES)
def test_state_carries_history(name):
    model = build_model(name).eval()  # SOGMP draws its latent in training mode
    _randomise_head(model)
    seq = _seq(1, 3, seed=1)
    out_with_history, _ = model(seq)
    out_alone, _ = model(seq[:, 2:])
    assert not torch.allclose(out_with_history[:, 2], out_alone[:, 0])


def test_untrained_flownet_predicts_copy_last():
    net = build_model("flownet")
    seq = _seq(2, 5, 20, 17, seed=3)
    flows, _ = net(seq)
    assert flows.abs().max() == 0
    for t in range(5):
        torch.testing.assert_close(net.predict_next(seq[:, t], flows[:, t]), seq[:, t, 0:1])


def test_flownet_predict_next_warps_occupancy_by_the_backward_flow():
    net = build_model("flownet")
    maps = torch.zeros(1, 2, 6, 8)
    maps[0, 0, 2, 3] = 1.0
    out = torch.zeros(1, 4, 6, 8)
    out[:, 0] = -1.0  # B_col: each cell samples one column to its left, so things move right
    out[:, 2:] = 7.0  # the forward flow must not matter
    expected = torch.zeros(1, 1, 6, 8)
    expected[0, 0, 2, 4] = 1.0
    torch.testing.assert_close(net.predict_next(maps, out), expected)


def test_untrained_deeptracking_predicts_the_prior_on_empty_maps():
    net = build_model("deeptracking")
    seq = torch.zeros(1, 3, 2, 9, 9)
    logits, _ = net(seq)
    p = net.predict_next(seq[:, -1], logits[:, -1])
    assert 0.001 < p.mean() < 0.2


@pytest.mark.parametrize("name", MODEL_NAMES)
def test_gradients_reach_every_parameter(name):
    model = build_model(name)
    _randomise_head(model)
    out, _ = model(_seq(2, 3))
    out.square().mean().backward()
    for pname, p in model.named_parameters():
        assert p.grad is not None and p.grad.abs().sum() > 0, pname


def test_zero_initialised_flow_head_still_learns():
    net = build_model("flownet")
    out, _ = net(_seq(2, 3))
    (out - 1.0).square().mean().backward()
    assert net.flow.conv_flow.weight.grad.abs().sum() > 0


def test_step_exports_without_data_dependent_branches():
    net = build_model("flownet")
    maps = _seq(1, 1, 12, 10)[:, 0]

    class Step(torch.nn.Module):
        def __init__(self, model):
            super().__init__()
            self.model = model

        def forward(self, maps, s0, s1, s2):
            out, state = self.model.step(maps, (s0, s1, s2))
            return (self.model.predict_next(maps, out), out, *state)

    exported = torch.export.export(Step(net), (maps, *net.init_state(1, 12, 10)))
    result = exported.module()(maps, *net.init_state(1, 12, 10))
    torch.testing.assert_close(result[0], maps[:, 0:1])


def test_occupancy_head_starts_as_copy_last_and_adds_one_channel():
    net = build_model("flownet", occupancy_head=True)
    assert net.out_channels == 5
    assert count_parameters(net) == PAPER_PARAMETERS + (1 + 2) + 1 + 1  # 1x1 head + gain
    seq = _seq(2, 4, 20, 17, seed=4)
    out, _ = net(seq)
    assert out.shape == (2, 4, 5, 20, 17) and out[:, :, :4].abs().max() == 0
    for t in range(4):
        prob = net.predict_next(seq[:, t], out[:, t])
        assert torch.equal(prob >= 0.4, seq[:, t, 0:1] > 0.5)
        torch.testing.assert_close(prob.max(), torch.tensor(0.9))
        torch.testing.assert_close(prob.min(), torch.tensor(0.01))


def test_occupancy_head_residual_moves_the_probability_and_flow_still_warps():
    net = build_model("flownet", occupancy_head=True)
    maps = torch.zeros(1, 2, 6, 8)
    maps[0, 0, 2, 3] = 1.0
    out = torch.zeros(1, 5, 6, 8)
    out[:, 0] = -1.0  # move right by one column, as in the flow-only test
    out[0, 4, 0, 0] = 10.0  # a residual logit alone turns a free cell occupied
    logit = net.next_logit(maps, out)
    expected = torch.zeros(1, 1, 6, 8)
    expected[0, 0, 2, 4] = net.warp_gain()
    expected[0, 0, 0, 0] = 10.0
    torch.testing.assert_close(logit, expected)
    torch.testing.assert_close(net.predict_next(maps, out), torch.sigmoid(expected))
    with pytest.raises(ValueError, match="occupancy head"):
        build_model("flownet").next_logit(maps, out[:, :4])


def test_occupancy_memory_is_an_exponential_average_of_past_maps():
    net = build_model("flownet", occupancy_head=True, memory_decays=(0.5, 0.8))
    assert net.state_channels() == (16, 16, 16, 2)
    maps = torch.zeros(1, 2, 5, 5)
    maps[0, 0, 1, 1] = 1.0
    state = net.init_state(1, 5, 5)
    for _ in range(3):
        _, state = net.step(maps, state)
    memory = state[-1][0, :, 1, 1]
    torch.testing.assert_close(memory, torch.tensor([1 - 0.5**3, 1 - 0.8**3]))
    assert state[-1][0, :, 0, 0].abs().max() == 0
    with pytest.raises(ModelError, match="memory_decays"):
        build_model("flownet", occupancy_head=True, memory_decays=(1.5,))


def test_constant_velocity_input_feeds_the_baselines_map_to_the_head():
    net = build_model("flownet", occupancy_head=True, constant_velocity_input=True)
    plain = build_model("flownet", occupancy_head=True)
    assert net.state_channels() == (16, 16, 16, 3)  # two memories and the previous map
    assert count_parameters(net) == count_parameters(plain) + 1
    scene = torch.zeros(1, 2, 10, 10)
    scene[0, 0, 4:6, 2] = 1.0
    moved = torch.roll(scene, shifts=(1, 2), dims=(2, 3))  # 1 row down, 2 columns right
    # Untrained, the new input's weights are zero: the prediction is the plain head's.
    state, state_plain = net.init_state(1, 10, 10), plain.init_state(1, 10, 10)
    for maps in (scene, moved):
        out, state = net.step(maps, state)
        out_plain, state_plain = plain.step(maps, state_plain)
        torch.testing.assert_close(out, out_plain)
    torch.testing.assert_close(state[-1][:, -1:], moved[:, 0:1])  # the previous map is kept
    # Read the constant-velocity channel's centre tap alone: the residual is that map.
    with torch.no_grad():
        net.head.out.weight.zero_()
        net.head.out.bias.zero_()
        net.head.out.weight[0, -1, 0, 0] = 1.0
    state = net.init_state(1, 10, 10)
    for maps in (scene, moved):
        out, state = net.step(maps, state)
    expected = torch.roll(moved[:, 0:1], shifts=(1, 2), dims=(2, 3))
    torch.testing.assert_close(out[:, 4:5], expected)
    with pytest.raises((ValueError, ModelError), match="constant_velocity_input"):
        build_model("flownet", constant_velocity_input=True)


def _moving_blob(frames: int, size: int = 16) -> list[torch.Tensor]:
    """A 2x2 object moving one column right per frame, away from the borders."""
    out = []
    for t in range(frames):
        maps = torch.zeros(1, 2, size, size)
        maps[0, 0, 6:8, 3 + t : 5 + t] = 1.0
        maps[0, 1] = 1.0
        out.append(maps)
    return out


def test_shifted_memories_average_the_moving_world_and_equal_still_ones_when_nothing_moves():
    kwargs = {"occupancy_head": True, "constant_velocity_input": True, "head_hidden_channels": 4}
    torch.manual_seed(0)
    still = build_model("flownet", zero_init_flow=False, **kwargs)
    shifting = build_model("flownet", zero_init_flow=False, shift_memories=True, **kwargs)
    with torch.no_grad():
        still.head.out.weight.normal_()
    shifting.load_state_dict(still.state_dict())  # the option adds no parameter
    # Nothing moves: the shift is zero, and the two models are the same function.
    maps = (_seq(1, 1, 16, 16, seed=4)[:, 0] > 0.5).float()
    s_still, s_shift = still.init_state(1, 16, 16), shifting.init_state(1, 16, 16)
    for _ in range(4):
        o_still, s_still = still.step(maps, s_still)
        o_shift, s_shift = shifting.step(maps, s_shift)
        torch.testing.assert_close(o_shift, o_still)
    # A moving object: with the shift every memory is the object itself (times 1 - d^t, the
    # zero start's weight), where still memories smear it along its track.
    frames = _moving_blob(6)
    s_still, s_shift = still.init_state(1, 16, 16), shifting.init_state(1, 16, 16)
    for maps in frames:
        _, s_still = still.step(maps, s_still)
        _, s_shift = shifting.step(maps, s_shift)
    current = frames[-1][0, 0]
    decays = torch.tensor(shifting.head.config.memory_decays).view(-1, 1, 1)
    k = len(decays)
    expected = (1.0 - decays ** len(frames)) * current
    torch.testing.assert_close(s_shift[-1][0, :k], expected)
    # Still memories keep some of the object where it was, behind it.
    assert torch.all(s_still[-1][0, :k, 6:8, 3:7].sum(dim=(1, 2)) > 0.1)
    with pytest.raises((ValueError, ModelError), match="shift_memories"):
        build_model("flownet", occupancy_head=True, shift_memories=True)


def test_hidden_head_starts_as_copy_last_and_its_layers_are_the_heads():
    from lidarflow.train.model_setup import is_head as _is_head

    net = build_model("flownet", occupancy_head=True, head_hidden_channels=8)
    features = 1 + 2  # O^t and two memories: each cell's own past
    assert count_parameters(net) == PAPER_PARAMETERS + features * 8 + 8 + 8 + 1 + 1
    heads = [n for n, _ in net.named_parameters() if _is_head(n)]
    assert set(heads) == {"head.hidden.weight", "head.hidden.bias", "head.out.weight"} | {
        "head.out.bias",
        "head.gain",
    }
    seq = _seq(1, 3, 12, 10, seed=5)
    out, _ = net(seq)
    for t in range(3):
        prob = net.predict_next(seq[:, t], out[:, t])
        assert torch.equal(prob >= 0.4, seq[:, t, 0:1] > 0.5)
    # The hidden layer is live: with a non-zero output layer the residual depends on the input.
    with torch.no_grad():
        net.head.out.weight.fill_(1.0)
    out, _ = net(seq)
    assert out[:, :, 4].std() > 0
    with pytest.raises((ValueError, ModelError), match="head_hidden_channels"):
        build_model("flownet", head_hidden_channels=4)


def test_subcell_input_reaches_the_head_and_only_the_head():
    kwargs = {"occupancy_head": True, "head_hidden_channels": 4}
    plain = build_model("flownet", **kwargs)
    net = build_model("flownet", **kwargs, subcell_input=True)
    assert (plain.input_channels, net.input_channels) == (2, 4)
    assert (takes_subcell(plain.input_channels), takes_subcell(net.input_channels)) == (False, True)
    assert count_parameters(net) == count_parameters(plain) + 2 * 4  # two more head inputs
    assert build_model("flownet", **kwargs, subcell_input=True, ego_motion=True).input_channels == 4
    scene = torch.zeros(1, 4, 8, 8)
    scene[0, 0, 3, 3] = scene[0, 1, 3:, :] = 1.0
    # Untrained (output layer zero) the edge and near channels change nothing: still copy-last.
    moved = scene.clone()
    moved[0, 2, 3, 3] = moved[0, 3, 2, 3] = 1.0
    predict = [net.predict_next(s, net.step(s, net.init_state(1, 8, 8))[0]) for s in (scene, moved)]
    torch.testing.assert_close(predict[0], predict[1])
    with torch.no_grad():
        net.head.out.weight.fill_(1.0)
    (out, state), (out_moved, state_moved) = (
        net.step(s, net.init_state(1, 8, 8)) for s in (scene, moved)
    )
    # Trained, they move the residual of the cells they mark, and only those (a per-cell head),
    # while the flow network, which sees (O, V) only, and the memories are the same.
    changed = (out[0, 4] != out_moved[0, 4]).nonzero().tolist()
    assert changed == [[2, 3], [3, 3]]
    torch.testing.assert_close(out[:, :4], out_moved[:, :4])
    for a, b in zip(state, state_moved, strict=True):
        torch.testing.assert_close(a, b)
    with pytest.raises((ValueError, ModelError), match="subcell_input"):
        build_model("flownet", subcell_input=True)


def test_the_head_sees_each_cells_own_inputs_only():
    net = build_model("flownet", occupancy_head=True, head_hidden_channels=8, visibility_input=True)
    assert count_parameters(net) == PAPER_PARAMETERS + (1 + 2 + 1) * 8 + 8 + 8 + 1 + 1
    with torch.no_grad():
        for p in (net.head.hidden.weight, net.head.hidden.bias):
            p.uniform_(-1.0, 1.0)
        net.head.out.weight.fill_(1.0)
    scene = torch.zeros(1, 2, 10, 10)
    scene[0, 0, 4, 3] = 1.0
    scene[0, 1, :, :6] = 1.0  # visible: the left part of the grid
    out, _ = net.step(scene, net.init_state(1, 10, 10))
    # Equal wherever a cell's own inputs are equal (even the occupied cell's neighbours).
    residual = out[0, 4]
    for region in (scene[0, 1] == 1, scene[0, 1] == 0):
        empty = region & (scene[0, 0] == 0)
        torch.testing.assert_close(residual[empty], residual[empty][0].expand_as(residual[empty]))
    assert residual[4, 3] != residual[4, 4] != residual[4, 8]  # occupied / seen / unseen


def test_model_spec_reads_every_stored_form_and_writes_its_own():
    from lidarflow.models import FlowConfig, HeadConfig, ModelSpec

    stored = {
        "occupancy_head": True,
        "memory_decays": [0.5, 0.9],
        "constant_velocity_input": True,
        "shift_memories": True,
        "head_hidden_channels": 16,
        "head_kernel_size": 1,
        "head_flow_features": False,
        "subcell_input": True,
        "ego_motion": True,
        "poses_optional": True,
        "online_decision": True,
        "decision_offset": 1.2,
    }
    spec, decision = ModelSpec.from_kwargs("flownet", stored, stored=True)
    assert decision == {"online_decision": True, "decision_offset": 1.2}
    assert spec.head == HeadConfig((0.5, 0.9), True, True, 16, False, True)
    assert spec.flow == FlowConfig() and spec.ego_motion and spec.poses_optional
    again, none = ModelSpec.from_kwargs("flownet", spec.to_kwargs(), stored=True)
    assert again == spec and none == {}
    # A stored head without the per-cell shape is the removed 3x3 head with GRU features.
    with pytest.raises(ValueError, match="3x3 kernel"):
        ModelSpec.from_kwargs("flownet", {"occupancy_head": True}, stored=True)
    assert ModelSpec.from_kwargs("flownet", {"occupancy_head": True})[0].head == HeadConfig()
    # A removed option at its old default reads as the model without it.
    plain, _ = ModelSpec.from_kwargs("flownet", {"warp_input": False, "in_channels": 2})
    assert plain == ModelSpec()
    for option, value in (("warp_input", True), ("transition_memories", True)):
        with pytest.raises(ValueError, match=f"{option} was measured without gain"):
            ModelSpec.from_kwargs("flownet", {"occupancy_head": True, option: value})
    with pytest.raises(ValueError, match="poses_optional needs ego_motion"):
        ModelSpec.from_kwargs("flownet", {"poses_optional": True})


def test_weights_saved_before_the_blocks_load_into_them(tmp_path):
    import json

    from safetensors.torch import save_file

    from lidarflow.models.weights import load_trained, upgrade_state

    torch.manual_seed(3)
    net = build_model("flownet", occupancy_head=True, head_hidden_channels=4, ego_motion=True)
    old_names = {
        "flow.conv0.": "conv0.",
        "flow.grus.": "grus.",
        "flow.conv_flow.": "conv_flow.",
        "head.out.": "conv_occupancy.",
        "head.hidden.": "occupancy_hidden.",
        "head.gain": "warp_gain",
    }
    old = {}
    for key, value in net.state_dict().items():
        name = key.removeprefix("inner.")
        for new, before in old_names.items():
            if name.startswith(new):
                name = before + name[len(new) :]
        old["inner." + name] = value.contiguous()
    assert upgrade_state(old).keys() == net.state_dict().keys()
    save_file(old, tmp_path / "model.safetensors")
    kwargs = {"occupancy_head": True, "head_hidden_channels": 4, "head_kernel_size": 1}
    kwargs |= {"head_flow_features": False, "ego_motion": True, "decision_offset": 0.7}
    (tmp_path / "model.json").write_text(json.dumps({"model": "flownet", "model_kwargs": kwargs}))
    loaded, card = load_trained(tmp_path)
    for key, value in net.state_dict().items():
        torch.testing.assert_close(loaded.state_dict()[key], value)
    assert card["decision"] == {"offset": 0.7, "online": False, "movers": False}
