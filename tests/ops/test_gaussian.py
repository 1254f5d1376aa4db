"""Tests of the separable Gaussian filter of the loss."""

from __future__ import annotations

import math

import pytest
import torch
import torch.nn.functional as F
from hypothesis import given, settings
from hypothesis import strategies as st

from lidarflow.ops import gaussian_blur, gaussian_kernel1d, opencv_sigma


def test_size_one_is_identity():
    maps = torch.rand(2, 3, 6, 7)
    assert torch.equal(gaussian_blur(maps, 1), maps)


def test_opencv_sigma_rule_values():
    assert [round(opencv_sigma(k), 6) for k in (3, 5, 7, 9)] == [0.8, 1.1, 1.4, 1.7]


def test_kernel_matches_the_gaussian_formula():
    k = gaussian_kernel1d(5, dtype=torch.float64)
    s = 1.1
    raw = [math.exp(-(x * x) / (2 * s * s)) for x in (-2, -1, 0, 1, 2)]
    expected = torch.tensor([v / sum(raw) for v in raw], dtype=torch.float64)
    torch.testing.assert_close(k, expected)


@pytest.mark.parametrize("kernel_size", [3, 5, 9])
def test_separable_equals_full_2d_convolution(kernel_size):
    maps = torch.rand(2, 2, 11, 13, dtype=torch.float64)
    k = gaussian_kernel1d(kernel_size, dtype=torch.float64)
    k2 = torch.outer(k, k).expand(2, 1, kernel_size, kernel_size)
    expected = F.conv2d(maps, k2, padding=kernel_size // 2, groups=2)
    torch.testing.assert_close(gaussian_blur(maps, kernel_size), expected)


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 10_000), kernel_size=st.sampled_from([3, 5, 7, 9]))
def test_blur_preserves_mass_away_from_borders(seed, kernel_size):
    g = torch.Generator().manual_seed(seed)
    pad = kernel_size // 2
    maps = torch.zeros(1, 2, 20, 20)
    inner = torch.rand(1, 2, 20 - 2 * pad, 20 - 2 * pad, generator=g) > 0.8
    maps[..., pad:-pad, pad:-pad] = inner.float()
    out = gaussian_blur(maps, kernel_size)
    torch.testing.assert_close(out.sum(dim=(-2, -1)), maps.sum(dim=(-2, -1)))
    assert out.min() >= 0


def test_mass_leaks_at_the_border_with_zero_padding():
    maps = torch.zeros(1, 1, 9, 9)
    maps[0, 0, 0, 4] = 1.0
    assert gaussian_blur(maps, 5).sum() < 0.9


def test_delta_blurs_to_a_symmetric_peak():
    maps = torch.zeros(1, 1, 9, 9)
    maps[0, 0, 4, 4] = 1.0
    out = gaussian_blur(maps, 5)[0, 0]
    torch.testing.assert_close(out, out.T)
    torch.testing.assert_close(out, out.flip(0))
    assert out.argmax().item() == 4 * 9 + 4


@pytest.mark.parametrize("bad", [0, 2, -3, 4.0, True])
def test_bad_kernel_size_raises(bad):
    with pytest.raises(ValueError, match="kernel_size"):
        gaussian_blur(torch.zeros(1, 1, 5, 5), bad)


def test_bad_sigma_and_shape_raise():
    with pytest.raises(ValueError, match="sigma"):
        gaussian_blur(torch.zeros(1, 1, 5, 5), 3, sigma=0.0)
    with pytest.raises(ValueError, match=r"\(B, C, H, W\)"):
        gaussian_blur(torch.zeros(5, 5), 3)


def test_gradcheck():
    maps = torch.rand(1, 1, 5, 6, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda m: gaussian_blur(m, 5, sigma=1.3), (maps,))
