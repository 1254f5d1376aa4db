"""Tests of the flow loss (paper and variants), DeepTracking's loss and the filter schedule."""

from __future__ import annotations

import math

import pytest
import torch
import torch.nn.functional as F
from hypothesis import given, settings
from hypothesis import strategies as st

from lidarflow.losses import LossConfig, deeptracking_loss, flow_loss, gaussian_schedule
from lidarflow.models import build_model
from lidarflow.ops import gaussian_blur, warp


def _random_seq(b=2, t=6, h=12, w=14, seed=0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    occ = (torch.rand(b, t, 1, h, w, generator=g) > 0.85).float()
    vis = torch.maximum(occ, (torch.rand(b, t, 1, h, w, generator=g) > 0.3).float())
    return torch.cat([occ, vis], dim=2)


def _static_seq(b=2, t=6, h=12, w=14) -> torch.Tensor:
    return _random_seq(b, 1, h, w).expand(b, t, 2, h, w).contiguous()


def _moving_seq(t=6, h=16, w=16, velocity=(1, 2)) -> torch.Tensor:
    """A 2 x 2 block moving by ``velocity`` = (cols, rows) cells per frame, away from borders."""
    seq = torch.zeros(1, t, 2, h, w)
    seq[:, :, 1] = 1.0
    for i in range(t):
        r, c = 2 + velocity[1] * i, 2 + velocity[0] * i
        seq[0, i, 0, r : r + 2, c : c + 2] = 1.0
    return seq


def _reference_paper_loss(seq, flows, k, warmup):
    """Eq. 3 of the paper, written pair by pair."""
    total = []
    for t in range(warmup, seq.shape[1] - 1):
        o_t, o_n = seq[:, t, 0:1], seq[:, t + 1, 0:1]
        fwd = F.mse_loss(warp(gaussian_blur(o_n, k), flows[:, t, 2:4]), o_t)
        bwd = F.mse_loss(warp(gaussian_blur(o_t, k), flows[:, t, 0:2]), o_n)
        total.append(fwd + bwd)
    return torch.stack(total).mean()


def test_paper_loss_of_untrained_net_on_static_sequence_is_zero_at_k1():
    seq = _static_seq(t=12)
    flows, _ = build_model("flownet")(seq)
    # (zero flow samples at the cell centres up to float rounding of the normalised grid)
    assert flow_loss(seq, flows, 1, LossConfig.paper(), warmup=10).item() < 1e-10
    # the literal paper loss penalises zero flow once the source is blurred ...
    assert flow_loss(seq, flows, 9, LossConfig.paper(), warmup=10).item() > 0.01
    # ... blurring both sides keeps zero flow optimal on a static scene at every size
    for k in (3, 5, 9):
        assert flow_loss(seq, flows, k, LossConfig.blurred_both(), warmup=10).item() < 1e-12


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 1000), k=st.sampled_from([1, 3, 5, 9]), warmup=st.integers(0, 4))
def test_flow_loss_equals_the_papers_formula(seed, k, warmup):
    seq = _random_seq(seed=seed)
    flows = 2 * torch.randn(2, 6, 4, 12, 14, generator=torch.Generator().manual_seed(seed))
    expected = _reference_paper_loss(seq, flows, k, warmup)
    torch.testing.assert_close(flow_loss(seq, flows, k, LossConfig.paper(), warmup), expected)


def test_default_config_is_the_papers():
    assert LossConfig() == LossConfig.paper()
    assert LossConfig.blurred_both() == LossConfig(blur_target=True)


def test_true_flow_beats_zero_flow_on_a_moving_object():
    seq = _moving_seq(velocity=(1, 2))
    true = torch.zeros(1, 6, 4, 16, 16)
    true[:, :, 0], true[:, :, 1] = -1.0, -2.0  # backward: sample where it came from
    true[:, :, 2], true[:, :, 3] = 1.0, 2.0  # forward
    zero = torch.zeros_like(true)
    assert flow_loss(seq, true, 1, LossConfig.paper(), warmup=0).item() < 1e-12
    assert flow_loss(seq, zero, 1, LossConfig.paper(), warmup=0).item() > 0.01
    for cfg in (LossConfig.blurred_both(), LossConfig(visible_only=True, occupied_weight=5.0)):
        assert flow_loss(seq, true, 5, cfg, 0) < flow_loss(seq, zero, 5, cfg, 0)


def test_only_pairs_from_warmup_to_the_second_last_frame_count():
    seq = _random_seq(t=8)
    flows = torch.zeros(2, 8, 4, 12, 14, requires_grad=True)
    flow_loss(seq, flows, 5, LossConfig.paper(), warmup=3).backward()
    per_t = flows.grad.abs().sum(dim=(0, 2, 3, 4))
    assert per_t[:3].sum() == 0  # warm-up outputs
    assert per_t[-1] == 0  # the last output has no next frame in the sequence
    assert (per_t[3:-1] > 0).all()


def test_loss_gradient_reaches_the_flow_and_the_model():
    seq = _moving_seq(t=5)
    net = build_model("flownet")
    flows, _ = net(seq)
    loss = flow_loss(seq, flows, 5, LossConfig.paper(), warmup=1)
    loss.backward()
    assert net.flow.conv_flow.weight.grad.abs().sum() > 0


def test_forward_term_can_be_switched_off():
    seq = _random_seq()
    flows = torch.randn(2, 6, 4, 12, 14)
    other = flows.clone()
    other[:, :, 2:] += 3.0
    cfg = LossConfig(forward_term=False)
    assert flow_loss(seq, flows, 3, cfg, 1) == flow_loss(seq, other, 3, cfg, 1)
    assert flow_loss(seq, flows, 3, LossConfig(), 1) != flow_loss(seq, other, 3, LossConfig(), 1)


def test_visible_only_ignores_cells_hidden_in_the_target():
    seq = _random_seq(t=3)
    flows = torch.zeros(2, 3, 4, 12, 14)
    cfg = LossConfig(visible_only=True, forward_term=False)
    base = flow_loss(seq, flows, 1, cfg, warmup=0)
    changed = seq.clone()
    # the last frame is only ever a target here: flip its cells that it does not see
    hidden = changed[:, 2, 1] == 0
    occ = changed[:, 2, 0]
    occ[hidden] = 1.0 - occ[hidden]
    assert hidden.any()
    torch.testing.assert_close(flow_loss(changed, flows, 1, cfg, warmup=0), base)
    assert flow_loss(changed, flows, 1, LossConfig(forward_term=False), 0) != flow_loss(
        seq, flows, 1, LossConfig(forward_term=False), 0
    )


def test_occupied_weight_is_a_weighted_mean():
    seq = _random_seq(t=2)
    flows = torch.randn(2, 2, 4, 12, 14, generator=torch.Generator().manual_seed(1))
    cfg = LossConfig(occupied_weight=4.0, forward_term=False, blur_source=False)
    o_t, o_n = seq[:, 0, 0:1], seq[:, 1, 0:1]
    err = (warp(o_t, flows[:, 0, 0:2]) - o_n).square()
    w = 1 + 3 * o_n
    torch.testing.assert_close(flow_loss(seq, flows, 1, cfg, 0), (err * w).sum() / w.sum())


def test_bce_variant_matches_cross_entropy():
    seq = _random_seq(t=2)
    flows = torch.randn(2, 2, 4, 12, 14, generator=torch.Generator().manual_seed(2))
    cfg = LossConfig(bce=True, forward_term=False)
    o_t, o_n = seq[:, 0, 0:1], seq[:, 1, 0:1]
    pred = warp(gaussian_blur(o_t, 3), flows[:, 0, 0:2]).clamp(1e-6, 1 - 1e-6)
    expected = F.binary_cross_entropy(pred, o_n)
    torch.testing.assert_close(flow_loss(seq, flows, 3, cfg, 0), expected)


def test_smoothness_penalises_only_varying_flow():
    seq = _static_seq(t=3)
    constant = torch.full((2, 3, 4, 12, 14), 0.0)
    varying = torch.zeros_like(constant)
    varying[..., ::2] = 0.5
    cfg = LossConfig(smoothness=2.0, blur_target=True)
    assert flow_loss(seq, constant, 3, cfg, 0).item() < 1e-12
    plain = flow_loss(seq, varying, 3, cfg.replace(smoothness=0.0), 0)
    # half the column steps differ by 0.5 (mean |d/dcol| = 0.5), rows never differ
    torch.testing.assert_close(flow_loss(seq, varying, 3, cfg, 0), plain + 2.0 * 0.5)


def test_bad_configs_and_shapes_raise():
    with pytest.raises(ValueError, match="occupied_weight"):
        LossConfig(occupied_weight=0.0)
    with pytest.raises(ValueError, match="smoothness"):
        LossConfig(smoothness=-1.0)
    seq = _random_seq(t=4)
    with pytest.raises(ValueError, match=r"\(B, T, 4, H, W\)"):
        flow_loss(seq, torch.zeros(2, 4, 2, 12, 14), 1, LossConfig())
    with pytest.raises(ValueError, match="warmup"):
        flow_loss(seq, torch.zeros(2, 4, 4, 12, 14), 1, LossConfig(), warmup=3)
    with pytest.raises(ValueError, match=r"seq must be"):
        flow_loss(seq[:, :, :1], torch.zeros(2, 4, 4, 12, 14), 1, LossConfig(), warmup=0)


def test_deeptracking_loss_is_masked_cross_entropy():
    seq = _random_seq(t=5)
    logits = torch.randn(2, 5, 1, 12, 14, generator=torch.Generator().manual_seed(3))
    target, vis = seq[:, 3:, 0:1], seq[:, 3:, 1:2]
    err = F.binary_cross_entropy_with_logits(logits[:, 2:4], target, reduction="none")
    expected = (err * vis).sum() / vis.sum()
    torch.testing.assert_close(deeptracking_loss(seq, logits, warmup=2), expected)
    torch.testing.assert_close(
        deeptracking_loss(seq, logits, warmup=2, visible_only=False), err.mean()
    )


def test_changed_cells_weighting_is_a_weighted_mean_by_hand():
    seq = _random_seq(t=5)
    logits = torch.randn(2, 5, 1, 12, 14, generator=torch.Generator().manual_seed(4))
    target, current = seq[:, 3:, 0:1], seq[:, 2:4, 0:1]
    err = F.binary_cross_entropy_with_logits(logits[:, 2:4], target, reduction="none")
    w = torch.where(target != current, 5.0, 1.0)
    expected = (err * w).sum() / w.sum()
    got = deeptracking_loss(seq, logits, warmup=2, visible_only=False, changed_weight=5.0)
    torch.testing.assert_close(got, expected)
    # Weighting changes the loss only where cells change: on a static sequence it is the mean.
    static = _static_seq(t=5)
    plain = deeptracking_loss(static, logits, warmup=2, visible_only=False)
    torch.testing.assert_close(
        deeptracking_loss(static, logits, warmup=2, visible_only=False, changed_weight=5.0), plain
    )
    with pytest.raises(ValueError, match="occupancy_changed_weight"):
        LossConfig(occupancy_changed_weight=0.0)


def test_deeptracking_loss_is_near_zero_for_confident_correct_logits():
    seq = _random_seq(t=4)
    logits = torch.zeros(2, 4, 1, 12, 14)
    logits[:, :-1] = 40.0 * (2 * seq[:, 1:, 0:1] - 1)
    assert deeptracking_loss(seq, logits, warmup=0).item() < 1e-9
    logits[:, :-1] = -logits[:, :-1]
    assert deeptracking_loss(seq, logits, warmup=0).item() > 10


def test_gaussian_schedule_values():
    assert [gaussian_schedule(e) for e in range(0, 200, 25)] == [9, 7, 5, 3, 1, 1, 1, 1]
    assert gaussian_schedule(24) == 9 and gaussian_schedule(25) == 7
    assert gaussian_schedule(10, start=5, step_epochs=5, minimum=3) == 3
    assert gaussian_schedule(0, start=1) == 1
    for bad in ({"epoch": -1}, {"epoch": 0, "start": 8}, {"epoch": 0, "step_epochs": 0}):
        with pytest.raises(ValueError):
            gaussian_schedule(**bad)


def test_loss_is_finite_under_random_flows():
    seq = _random_seq()
    flows = 50 * torch.randn(2, 6, 4, 12, 14)
    for cfg in (LossConfig(), LossConfig(bce=True, visible_only=True, occupied_weight=3.0)):
        assert math.isfinite(flow_loss(seq, flows, 9, cfg, 2).item())
