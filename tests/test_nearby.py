"""Cells near other cells: the disc, and counting through it as the dilation does."""

from __future__ import annotations

import doctest

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

import lidarflow.nearby as nearby


def test_the_doctests_hold():
    assert doctest.testmod(nearby, raise_on_error=True).attempted >= 2


@settings(max_examples=60)
@given(
    st.integers(1, 9), st.integers(1, 9), st.integers(0, 3), st.integers(1, 3), st.integers(0, 99)
)
def test_near_counts_counts_the_cells_near_each_map(h, w, radius, maps, seed):
    rng = np.random.default_rng(seed)
    masks = rng.random((maps, h, w)) < rng.random((maps, 1, 1))
    cells = rng.random((h, w)) < 0.4
    expected = np.count_nonzero(cells & nearby.near(masks, radius), axis=(1, 2))
    np.testing.assert_array_equal(nearby.near_counts(masks, cells, radius), expected)
    span = range(-radius, radius + 1)
    disc = {(a, b) for a in span for b in span if a * a + b * b <= radius * radius}
    assert sorted(map(tuple, nearby.disc(radius).tolist())) == sorted(disc)
