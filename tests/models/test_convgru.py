"""Tests of the fused ConvGRU cell against the paper's equations written out unfused."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from lidarflow.models import ConvGRUCell


def _unfused_reference(cell: ConvGRUCell, x: torch.Tensor, y_prev: torch.Tensor) -> torch.Tensor:
    """Paper eq. 1 with six separate convolutions, using the blocks of the fused weights."""
    c = cell.hidden_channels
    d = cell.dilation
    wx, bx, wy = cell.conv_x.weight, cell.conv_x.bias, cell.conv_y.weight

    def conv(inp, w, b=None):
        return F.conv2d(inp, w, b, padding=d, dilation=d)

    w_xf, w_xr, w_xy = wx[:c], wx[c : 2 * c], wx[2 * c :]
    b_f, b_r, b_y = bx[:c], bx[c : 2 * c], bx[2 * c :]
    w_yf, w_yr, w_yy = wy[:c], wy[c : 2 * c], wy[2 * c :]
    f = torch.sigmoid(conv(x, w_xf, b_f) + conv(y_prev, w_yf))
    r = torch.sigmoid(conv(x, w_xr, b_r) + conv(y_prev, w_yr))
    ybar = torch.tanh(conv(x, w_xy, b_y) + r * conv(y_prev, w_yy))
    return f * y_prev + (1 - f) * ybar


@pytest.mark.parametrize("dilation", [1, 2, 4])
def test_fused_cell_equals_the_papers_equations(dilation):
    torch.manual_seed(dilation)
    cell = ConvGRUCell(3, 5, dilation=dilation).double()
    x = torch.randn(2, 3, 11, 13, dtype=torch.float64)
    y_prev = torch.randn(2, 5, 11, 13, dtype=torch.float64)
    torch.testing.assert_close(cell(x, y_prev), _unfused_reference(cell, x, y_prev))


@pytest.mark.parametrize(("h", "w"), [(8, 8), (17, 5), (100, 100)])
def test_same_padding_keeps_the_grid_for_every_dilation(h, w):
    for d in (1, 2, 4):
        cell = ConvGRUCell(2, 4, dilation=d)
        assert cell(torch.zeros(1, 2, h, w), torch.zeros(1, 4, h, w)).shape == (1, 4, h, w)


def test_state_is_carried():
    torch.manual_seed(0)
    cell = ConvGRUCell(2, 4)
    x = torch.randn(1, 2, 6, 6)
    y1 = cell(x, torch.zeros(1, 4, 6, 6))
    y2 = cell(x, y1)
    assert not torch.allclose(y1, y2)
    # with the update gate forced open (f = 1) the state passes through unchanged
    with torch.no_grad():
        cell.conv_x.bias[:4] = 1e4
    torch.testing.assert_close(cell(x, y1), y1)


def test_output_is_bounded_by_tanh_and_previous_state():
    torch.manual_seed(1)
    cell = ConvGRUCell(2, 4)
    y = cell(10 * torch.randn(3, 2, 7, 7), torch.zeros(3, 4, 7, 7))
    assert y.abs().max() < 1.0


def test_parameter_count_and_biases():
    cell = ConvGRUCell(16, 16, dilation=2)
    # six 16 -> 16 3x3 kernels plus one bias per gate channel
    assert sum(p.numel() for p in cell.parameters()) == 6 * 16 * 16 * 9 + 3 * 16
    assert cell.conv_y.bias is None


def test_even_kernel_is_rejected():
    with pytest.raises(ValueError, match="odd"):
        ConvGRUCell(2, 4, kernel_size=2)
