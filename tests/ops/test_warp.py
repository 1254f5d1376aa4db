"""Tests of the bilinear warp: identity, exact integer shifts, the flow sign convention, borders,
fractional values, bad input and gradients."""

from __future__ import annotations

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from lidarflow.ops import warp
from lidarflow.ops.warp import _base_grid, warp_gather


def _random_maps(seed: int, shape=(2, 3, 7, 9), dtype=torch.float32) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return torch.rand(shape, generator=g, dtype=dtype)


def _shift_reference(maps: torch.Tensor, dx: int, dy: int) -> torch.Tensor:
    """out[r, c] = maps[r + dy, c + dx], zero where that is outside: written with slicing."""
    out = torch.zeros_like(maps)
    h, w = maps.shape[-2:]
    for r in range(h):
        for c in range(w):
            if 0 <= r + dy < h and 0 <= c + dx < w:
                out[..., r, c] = maps[..., r + dy, c + dx]
    return out


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), h=st.integers(2, 12), w=st.integers(2, 12))
def test_zero_flow_is_identity(seed, h, w):
    maps = _random_maps(seed, (2, 3, h, w))
    out = warp(maps, torch.zeros(2, 2, h, w))
    torch.testing.assert_close(out, maps, atol=1e-6, rtol=0)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), dx=st.integers(-6, 6), dy=st.integers(-6, 6))
def test_integer_flow_shifts_exactly(seed, dx, dy):
    g = torch.Generator().manual_seed(seed)
    maps = (torch.rand(1, 1, 7, 9, generator=g) > 0.7).float()
    flow = torch.empty(1, 2, 7, 9)
    flow[:, 0] = dx
    flow[:, 1] = dy
    torch.testing.assert_close(warp(maps, flow), _shift_reference(maps, dx, dy), atol=1e-6, rtol=0)


def test_backward_flow_convention_moves_object_as_design_notes_say():
    # An object at (row 2, col 3) moves to (row 4, col 6) between t and t+1.
    o_t = torch.zeros(1, 1, 8, 10)
    o_t[0, 0, 2, 3] = 1.0
    o_next = torch.zeros(1, 1, 8, 10)
    o_next[0, 0, 4, 6] = 1.0
    # O^{t+1}(p) = O^t(p + B(p)): at the new position the flow points back to the old one.
    backward = torch.zeros(1, 2, 8, 10)
    backward[:, 0] = 3 - 6  # column displacement first
    backward[:, 1] = 2 - 4  # then rows
    torch.testing.assert_close(warp(o_t, backward), o_next)
    # and the forward flow, O^t(p) = O^{t+1}(p + F(p)), is its negative for a rigid shift
    torch.testing.assert_close(warp(o_next, -backward), o_t)


def test_samples_outside_the_map_are_zero():
    maps = torch.ones(1, 2, 5, 6)
    flow = torch.zeros(1, 2, 5, 6)
    flow[:, 0] = 6.0  # every sample lands at least one column beyond the right edge
    assert warp(maps, flow).abs().max().item() == 0.0
    flow[:, 0] = 0.0
    flow[:, 1] = -5.5  # above the top edge, even with the half cell of bilinear support
    assert warp(maps, flow).abs().max().item() == 0.0
    # half a cell beyond the edge blends with the zero outside
    flow[:, 1] = 0.0
    flow[:, 0, :, -1] = 0.5
    out = warp(maps, flow)
    torch.testing.assert_close(out[..., -1], torch.full((1, 2, 5), 0.5))
    torch.testing.assert_close(out[..., :-1], torch.ones(1, 2, 5, 5))


def test_fractional_flow_interpolates_bilinearly():
    maps = torch.arange(20, dtype=torch.float32).view(1, 1, 4, 5)  # value = 5 r + c
    flow = torch.zeros(1, 2, 4, 5)
    flow[:, 0] = 0.25
    flow[:, 1] = 0.5
    out = warp(maps, flow)
    # inside the map, bilinear interpolation of a linear function is exact
    expected = maps + 0.25 + 5 * 0.5
    torch.testing.assert_close(out[..., :-1, :-1], expected[..., :-1, :-1])


def test_per_cell_flow_and_batch_items_are_independent():
    maps = _random_maps(1, (2, 1, 6, 6))
    flow = torch.zeros(2, 2, 6, 6)
    flow[1, 0, 2, 3] = -2.0  # only cell (2, 3) of item 1 samples from (2, 1)
    out = warp(maps, flow)
    torch.testing.assert_close(out[0], maps[0])
    assert out[1, 0, 2, 3] == maps[1, 0, 2, 1]
    mask = torch.ones(6, 6, dtype=torch.bool)
    mask[2, 3] = False
    torch.testing.assert_close(out[1, 0][mask], maps[1, 0][mask])


@pytest.mark.parametrize(
    ("maps_shape", "flow_shape", "match"),
    [
        ((1, 5, 5), (1, 2, 5, 5), "maps must be"),
        ((1, 1, 5, 5), (1, 3, 5, 5), "flow must be"),
        ((1, 1, 5, 5), (2, 2, 5, 5), "does not match"),
        ((1, 1, 5, 5), (1, 2, 5, 4), "does not match"),
        ((1, 1, 1, 5), (1, 2, 1, 5), "at least 2 x 2"),
    ],
)
def test_bad_shapes_raise_value_error_naming_them(maps_shape, flow_shape, match):
    with pytest.raises(ValueError, match=match):
        warp(torch.zeros(maps_shape), torch.zeros(flow_shape))


def test_integer_maps_are_rejected():
    with pytest.raises(ValueError, match="floating point"):
        warp(torch.zeros(1, 1, 4, 4, dtype=torch.uint8), torch.zeros(1, 2, 4, 4))


def test_gradcheck_wrt_maps_and_flow():
    g = torch.Generator().manual_seed(0)
    maps = torch.rand(2, 2, 5, 6, generator=g, dtype=torch.float64, requires_grad=True)
    # fractional parts kept away from 0 so no sample sits on a kink of the bilinear kernel
    whole = torch.randint(-2, 3, (2, 2, 5, 6), generator=g).double()
    frac = 0.2 + 0.6 * torch.rand(2, 2, 5, 6, generator=g, dtype=torch.float64)
    flow = (whole + frac).requires_grad_(True)
    assert torch.autograd.gradcheck(warp, (maps, flow), eps=1e-6, atol=1e-5)


def test_gradient_reaches_flow_and_points_towards_the_target():
    o_t = torch.zeros(1, 1, 1, 8).expand(1, 1, 2, 8).clone()
    o_t[..., 3] = 1.0
    target = torch.zeros_like(o_t)
    target[..., 5] = 1.0  # moved 2 cells right: the right backward flow at col 5 is -2
    flow = torch.zeros(1, 2, 2, 8)
    flow[:, 0] = -1.5
    flow.requires_grad_(True)
    loss = ((warp(o_t, flow) - target) ** 2).sum()
    loss.backward()
    assert flow.grad is not None
    # at col 5 sampling at 3.5 gives 0.5; decreasing the flow (towards -2) lowers the loss
    assert flow.grad[0, 0, 0, 5] > 0


def test_base_grid_is_cached_per_size():
    a = _base_grid(4, 5, torch.device("cpu"), torch.float32)
    b = _base_grid(4, 5, torch.device("cpu"), torch.float32)
    assert a[0] is b[0]
    assert a[0].shape == (1, 4, 5, 2)


def test_low_precision_flow_is_sampled_in_the_maps_precision():
    maps = _random_maps(3, (1, 1, 6, 6))
    flow = torch.full((1, 2, 6, 6), 1.0, dtype=torch.bfloat16)
    out = warp(maps, flow)
    assert out.dtype == torch.float32
    torch.testing.assert_close(out, _shift_reference(maps, 1, 1))


def test_warp_used_in_inference_mode_first_still_trains():
    # Regression: the cached sampling grid was created as an inference tensor when the first
    # call ran under torch.inference_mode, and every later autograd call then failed.
    size = (1, 1, 13, 17)  # a size no other test uses, so the cache starts empty for it
    with torch.inference_mode():
        warp(torch.zeros(size), torch.zeros(1, 2, 13, 17))
    flow = torch.zeros(1, 2, 13, 17, requires_grad=True)
    warp(torch.rand(size), flow).sum().backward()
    assert flow.grad is not None


@settings(max_examples=30, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    b=st.integers(1, 3),
    c=st.integers(1, 6),
    h=st.integers(2, 10),
    w=st.integers(2, 10),
    scale=st.sampled_from([0.3, 2.0, 8.0]),
)
def test_warp_gather_is_the_same_function_as_warp(seed, b, c, h, w, scale):
    # Flows reach far outside the grid (zeros there) and land on whole cells (border cases).
    g = torch.Generator().manual_seed(seed)
    maps = torch.rand(b, c, h, w, generator=g, dtype=torch.float64)
    flow = torch.randn(b, 2, h, w, generator=g, dtype=torch.float64) * scale
    flow[:, :, 0] = torch.round(flow[:, :, 0])
    torch.testing.assert_close(warp_gather(maps, flow), warp(maps, flow), atol=1e-12, rtol=0)


def test_warp_gather_has_warps_gradients_and_checks():
    torch.manual_seed(3)
    maps = torch.rand(2, 3, 6, 5, dtype=torch.float64, requires_grad=True)
    flow = (torch.randn(2, 2, 6, 5, dtype=torch.float64) * 1.7).requires_grad_()
    # Away from whole cells (where bilinear sampling has a kink) the two gradients agree.
    with torch.no_grad():
        flow += 0.25 * (flow.frac().abs() < 0.05)
    assert torch.autograd.gradcheck(warp_gather, (maps, flow))
    for fn in (warp, warp_gather):
        maps.grad = flow.grad = None
        (fn(maps, flow) * torch.arange(180, dtype=torch.float64).view(2, 3, 6, 5)).sum().backward()
        if fn is warp:
            reference = (maps.grad.clone(), flow.grad.clone())
    torch.testing.assert_close((maps.grad, flow.grad), reference)
    with pytest.raises(ValueError, match="flow must be"):
        warp_gather(maps, flow[:, :1])
