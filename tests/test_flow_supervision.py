"""The supervised flow loss: zero for exact flow, grows with the error, weights what moves."""

from __future__ import annotations

import pytest
import torch
from hypothesis import given
from hypothesis import strategies as st

from lidarflow.flow_supervision import (
    flow_epe_loss,
    moving_cells,
    platform_flows,
    window_flow_loss,
)
from lidarflow.ops.rigid import cell_grid, transform_cells


def _case(seed: int, n: int = 2, d: int = 2, h: int = 6, w: int = 5):
    g = torch.Generator().manual_seed(seed)
    truth = torch.randn(n, 2 * d, h, w, generator=g, dtype=torch.float64)
    defined = torch.rand(n, d, h, w, generator=g) < 0.6
    moving = torch.rand(n, d, h, w, generator=g) < 0.2
    return truth, defined, moving


@given(st.integers(0, 10_000), st.sampled_from([1, 2]))
def test_exact_flow_costs_nothing(seed, d):
    truth, defined, moving = _case(seed, d=d)
    assert float(flow_epe_loss(truth.clone(), truth, defined, moving)) == 0.0


@given(st.integers(0, 10_000), st.floats(0.05, 3.0), st.floats(1.1, 4.0))
def test_the_loss_grows_with_the_error(seed, scale, factor):
    truth, defined, moving = _case(seed)
    defined[0, 0, 0, 0] = True  # at least one counted cell
    g = torch.Generator().manual_seed(seed + 1)
    direction = torch.randn(truth.shape, generator=g, dtype=torch.float64)
    small = flow_epe_loss(truth + scale * direction, truth, defined, moving)
    large = flow_epe_loss(truth + factor * scale * direction, truth, defined, moving)
    assert 0.0 < float(small) < float(large)


def test_an_error_far_above_eps_costs_its_end_point_error():
    truth = torch.zeros(1, 2, 3, 3)
    flow = truth.clone()
    flow[0, :, 1, 1] = torch.tensor([3.0, 4.0])  # 5 cells off
    defined = torch.zeros(1, 1, 3, 3, dtype=torch.bool)
    defined[0, 0, 1, 1] = True
    loss = flow_epe_loss(flow, truth, defined, torch.zeros_like(defined))
    assert float(loss) == pytest.approx(5.0, abs=2e-3)


def test_moving_cells_weigh_moving_weight_times_a_static_one():
    # one moving cell 1 cell off, nine static cells exact: mean = k / (k + 9) for weight k
    truth = torch.zeros(1, 2, 1, 10, dtype=torch.float64)
    flow = truth.clone()
    flow[0, 0, 0, 0] = 1.0
    defined = torch.ones(1, 1, 1, 10, dtype=torch.bool)
    moving = torch.zeros_like(defined)
    moving[0, 0, 0, 0] = True
    for k in (1.0, 10.0, 50.0):
        loss = flow_epe_loss(flow, truth, defined, moving, moving_weight=k)
        assert float(loss) == pytest.approx(k / (k + 9), rel=1e-3)
    # the same error on a static cell is drowned by the weighted moving one
    moving[0, 0, 0, 0], moving[0, 0, 0, 5] = False, True
    assert float(flow_epe_loss(flow, truth, defined, moving, 10.0)) == pytest.approx(
        1 / 19, rel=1e-3
    )


def test_cells_where_the_truth_is_undefined_do_not_count():
    truth, defined, moving = _case(3)
    flow = truth + 100.0 * (~defined).repeat_interleave(2, dim=1)
    assert float(flow_epe_loss(flow, truth, defined, moving)) == 0.0
    nothing = torch.zeros_like(defined)
    assert float(flow_epe_loss(flow + 1, truth, nothing, moving)) == 0.0


def test_gradcheck_float64():
    truth, defined, moving = _case(7, n=1, h=3, w=3)
    flow = (truth + 0.3 * torch.randn_like(truth)).requires_grad_(True)
    assert torch.autograd.gradcheck(
        lambda f: flow_epe_loss(f, truth, defined, moving, moving_weight=5.0), (flow,)
    )


def test_bad_shapes_and_weights_are_refused():
    truth, defined, moving = _case(0)
    with pytest.raises(ValueError, match="flow and truth"):
        flow_epe_loss(truth[:, :3], truth[:, :3], defined, moving)
    with pytest.raises(ValueError, match="defined and moving"):
        flow_epe_loss(truth, truth, defined[:, :1], moving)
    with pytest.raises(ValueError, match="moving_weight"):
        flow_epe_loss(truth, truth, defined, moving, moving_weight=-1.0)


def test_platform_flow_of_a_straight_drive_and_a_turn():
    h, w = 8, 6
    still = platform_flows(torch.zeros(1, 3), h, w)
    assert still.shape == (1, 4, h, w) and float(still.abs().max()) == 0.0
    ahead = platform_flows(torch.tensor([[2.0, 0.0, 0.0]]), h, w)  # 2 cells forward
    # a wall point seen at row r from t + 1 was 2 rows further (row - 2) at t, and back
    assert torch.allclose(ahead[0, :2], torch.tensor([0.0, -2.0]).view(2, 1, 1).expand(2, h, w))
    assert torch.allclose(ahead[0, 2:], torch.tensor([0.0, 2.0]).view(2, 1, 1).expand(2, h, w))
    # a turn: forward then backward flow brings a cell back where it started
    motion = torch.tensor([[0.7, -0.4, 0.2]], dtype=torch.float64)
    flows = platform_flows(motion, h, w)
    c, r = cell_grid(h, w, dtype=torch.float64)
    c1, r1 = c + flows[0, 2], r + flows[0, 3]  # forward from frame t to t + 1
    # the backward flow is affine: T(q) - q at the moved cells, in closed form
    c0, r0 = transform_cells(c1[None], r1[None], motion, h, w)
    assert torch.allclose(c0[0], c, atol=1e-9) and torch.allclose(r0[0], r, atol=1e-9)


def test_moving_cells_are_measured_against_the_platform():
    truth = torch.zeros(1, 2, 2, 2)
    truth[0, 1] = -2.0  # everything moves 2 rows back: the platform drove 2 cells ahead
    truth[0, 0, 1, 1] = 0.5  # one cell also moves half a cell sideways
    platform = platform_flows(torch.tensor([[2.0, 0.0, 0.0]]), 2, 2)[:, :2]
    assert moving_cells(truth, platform, 0.15)[0, 0].tolist() == [[False, False], [False, True]]
    assert bool(moving_cells(truth, None, 0.15).all())  # a standing platform: all of it moves


def _window(seed: int = 0, b: int = 2, t: int = 6, h: int = 5, w: int = 4):
    g = torch.Generator().manual_seed(seed)
    seq = (torch.rand(b, t, 2, h, w, generator=g) < 0.5).float()
    truth = torch.randn(b, t, 4, h, w, generator=g)
    motions = torch.randn(b, t, 3, generator=g) * 0.3
    return seq, truth, motions


def test_window_loss_counts_only_the_pairs_after_the_warmup():
    seq, truth, motions = _window()
    out = truth.clone()
    warmup = 2
    out[:, :warmup] += 5.0  # warm-up outputs and the last one (no next frame) are not taught
    out[:, -1] += 5.0
    assert float(window_flow_loss(seq, out, truth, motions, warmup, 10.0, 0.15)) == 0.0
    out[:, warmup, 0] += 1.0  # B^t of the first counted pair
    assert float(window_flow_loss(seq, out, truth, motions, warmup, 10.0, 0.15)) > 0.0
    backward_only = window_flow_loss(seq, out, truth[:, :, :2], None, warmup, 10.0, 0.15)
    assert float(backward_only) > 0.0


def test_window_loss_defines_b_on_the_next_map_and_f_on_the_current():
    seq, truth, _ = _window(1)
    out = truth.clone()
    t = 3
    out[:, t, 0:2] += (seq[:, t + 1, 0] < 0.5).unsqueeze(1) * 9.0  # B off where O^{t+1} is free
    out[:, t, 2:4] += (seq[:, t, 0] < 0.5).unsqueeze(1) * 9.0  # F off where O^t is free
    assert float(window_flow_loss(seq, out, truth, None, 1, 10.0, 0.15)) == 0.0
    out[:, t, 2:4] += (seq[:, t, 0] > 0.5).unsqueeze(1) * 9.0  # now also where F is defined
    assert float(window_flow_loss(seq, out, truth, None, 1, 10.0, 0.15)) > 0.0
