"""Tests of the ego-motion wrapper: identity when nothing moves, exact compensation of a static
world seen from a moving sensor, causality default, building/loading by kwargs, gradients."""

from __future__ import annotations

import pytest
import torch

from lidarflow.errors import ModelError
from lidarflow.models import EgoCompensated, build_model, uses_ego_motion
from lidarflow.models.egomotion import OCCUPANCY_FILL_LOGIT
from lidarflow.models.flownet import LidarFlowNet
from lidarflow.ops.rigid import rigid_warp
from lidarflow.ops.warp import warp


def _random_flownet(seed: int = 0) -> LidarFlowNet:
    torch.manual_seed(seed)
    net = build_model("flownet", zero_init_flow=False)
    for p in net.flow.conv_flow.parameters():
        p.data.mul_(0.3)
    return net.eval()


def test_identity_motion_equals_the_inner_model():
    inner = _random_flownet()
    ego = EgoCompensated(inner).eval()
    seq = (torch.rand(2, 4, 2, 10, 8) > 0.7).float()
    a, _ = inner(seq)
    b, _ = ego(seq, motions=torch.zeros(2, 4, 3))
    c, _ = ego(seq)
    torch.testing.assert_close(a, b, atol=1e-5, rtol=0)
    torch.testing.assert_close(a, c)


def test_state_is_warped_into_the_current_frame():
    inner = _random_flownet(1)
    ego = EgoCompensated(inner).eval()
    maps = (torch.rand(1, 2, 12, 10) > 0.6).float()
    state = tuple(torch.rand(1, c, 12, 10) for c in inner.state_channels())
    m = torch.tensor([[2.0, -1.0, 0.1]])
    _, s_ego = ego.step(maps, state, m, torch.zeros(1, 3))
    _, s_ref = inner.step(maps, tuple(rigid_warp(s, m) for s in state))
    for x, y in zip(s_ego, s_ref, strict=True):
        torch.testing.assert_close(x, y)


def test_untrained_wrapper_predicts_a_static_world_exactly_under_ego_motion():
    """Zero world flow + the true ego motion: the prediction of O^{t+1} is O^t moved into the
    t+1 frame, and the forward flow maps cells of O^t onto it (a round trip of the two flows)."""
    ego = EgoCompensated(build_model("flownet")).eval()  # zero-initialised flow head
    occ = torch.zeros(1, 1, 30, 30)
    occ[0, 0, 8:12, 5:25] = 1.0  # a wall ahead
    maps = torch.cat([occ, torch.ones_like(occ)], dim=1)
    m = torch.tensor([[3.0, 1.0, 0.0]])  # 3 cells forward, 1 left
    out, _ = ego.step(maps, ego.init_state(1, 30, 30), m, m)
    predicted = ego.predict_next(maps, out)
    torch.testing.assert_close(predicted, rigid_warp(occ, m), atol=1e-5, rtol=0)
    assert predicted[0, 0, 11:15, 6:26].min() > 0.99  # 3 rows closer, 1 column right
    # forward flow: O^t(p) = O^{t+1}(p + F(p))
    torch.testing.assert_close(warp(predicted, out[:, 2:4]) * occ, occ, atol=1e-5, rtol=0)


def test_forward_and_backward_ego_flows_are_inverse_under_rotation():
    # zero world flow: the flows are the ego flow
    zero = EgoCompensated(build_model("flownet")).eval()
    maps = (torch.rand(1, 2, 24, 24) > 0.8).float()
    m = torch.tensor([[1.5, 0.5, 0.08]])
    out, _ = zero.step(maps, zero.init_state(1, 24, 24), m, m)
    b0, f0 = out[:, 0:2], out[:, 2:4]
    roundtrip = f0 + warp(b0, f0)  # p -> p + F(p) -> (p + F) + B(p + F) == p
    assert roundtrip[:, :, 4:20, 4:20].abs().max() < 1e-3
    assert f0.abs().max() > 1.0


def test_constant_velocity_is_the_default_next_motion():
    ego = EgoCompensated(_random_flownet(4)).eval()
    seq = (torch.rand(1, 3, 2, 10, 10) > 0.7).float()
    motions = torch.tensor([[[0.0, 0, 0], [1.0, 0.5, 0.05], [2.0, 0.0, -0.1]]])
    a, _ = ego(seq, motions=motions)
    b, _ = ego(seq, motions=motions, next_motions=motions)
    torch.testing.assert_close(a, b)
    c, _ = ego(seq, motions=motions, next_motions=torch.roll(motions, -1, 1))
    assert not torch.allclose(a, c)


def test_built_by_kwargs_and_deeptracking_supported_with_gradients():
    net = build_model("flownet", ego_motion=True)
    assert isinstance(net, EgoCompensated) and uses_ego_motion(net)
    assert not uses_ego_motion(build_model("flownet"))
    assert len(net.inner.flow.grus) == 3
    dt = build_model("deeptracking", ego_motion=True)
    seq = torch.rand(2, 3, 2, 8, 8)
    motions = torch.rand(2, 3, 3, requires_grad=True)
    out, _ = dt(seq, motions=motions)
    assert out.shape == (2, 3, 1, 8, 8)
    out.sum().backward()
    assert motions.grad is not None and torch.isfinite(motions.grad).all()
    assert any(p.grad is not None for p in dt.parameters())


def test_bf16_autocast_keeps_the_ego_warp_in_fp32():
    # zero world flow: the output is the ego flow
    ego = EgoCompensated(build_model("flownet")).eval()
    seq = (torch.rand(1, 2, 2, 100, 100) > 0.8).float()
    motions = torch.tensor([[[0.0, 0.0, 0.0], [3.3, -1.7, 0.05]]])
    ref, _ = ego(seq, motions=motions)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        out, _ = ego(seq, motions=motions)
    assert out.dtype == torch.float32
    assert (out - ref).abs().max() < 1e-3  # bf16 cell coordinates would be off by ~0.25 cells


def test_occupancy_head_under_ego_motion_moves_its_residual_logit_rigidly():
    torch.manual_seed(5)
    kwargs = {"occupancy_head": True, "constant_velocity_input": True, "shift_memories": True}
    inner = build_model("flownet", zero_init_flow=False, head_hidden_channels=4, **kwargs)
    with torch.no_grad():
        inner.head.out.weight.normal_()
    ego = EgoCompensated(inner).eval()
    assert ego.capabilities.occupancy_head and ego.out_channels == 5
    maps = (torch.rand(1, 2, 16, 14) > 0.7).float()
    state = tuple(torch.rand(1, c, 16, 14) for c in inner.state_channels())
    m = torch.tensor([[2.0, -1.0, 0.1]])
    out, _ = ego.step(maps, state, m, m)
    ref, _ = inner.step(maps, tuple(rigid_warp(s, m) for s in state))
    expected = rigid_warp(ref[:, 4:5], m, fill=OCCUPANCY_FILL_LOGIT)
    torch.testing.assert_close(out[:, 4:5], expected, atol=1e-5, rtol=0)
    torch.testing.assert_close(ego.next_logit(maps, out), inner.next_logit(maps, out))
    # Untrained, the head is copy-last in the sensor's frame, so with the odometry it predicts
    # the last map moved into the next frame (an integer motion: exactly).
    untrained = EgoCompensated(build_model("flownet", **kwargs)).eval()
    occ = torch.zeros(1, 1, 30, 30)
    occ[0, 0, 8:12, 5:25] = 1.0
    maps = torch.cat([occ, torch.ones_like(occ)], dim=1)
    m = torch.tensor([[3.0, 1.0, 0.0]])
    out, _ = untrained.step(maps, untrained.init_state(1, 30, 30), m, m)
    predicted = untrained.predict_next(maps, out) >= 0.4
    assert torch.equal(predicted, rigid_warp(occ, m) > 0.5)
    assert not torch.equal(predicted, occ > 0.5)


def test_poses_optional_marks_an_ego_model_and_needs_ego_motion():
    assert build_model("flownet", ego_motion=True, poses_optional=True).poses_optional
    assert not build_model("flownet", ego_motion=True).poses_optional
    with pytest.raises(ModelError, match="poses_optional"):
        build_model("flownet", poses_optional=True)
