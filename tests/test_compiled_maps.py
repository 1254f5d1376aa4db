"""The compiled passes of rasterising and of the online decision's counts against their NumPy
references, to the bit: the maps and masks of the bundled sample's scans and of edge cases
(no returns, NaN / inf, readings at range_max, full and partial fields of view), the counts
and shifts exactly, and a Predictor's outputs on the sample."""

from __future__ import annotations

import math
from collections.abc import Callable
from functools import cache
from typing import Any

import numpy as np
import pytest

from lidarflow import beams, compiled
from lidarflow.baselines import best_rigid_shift
from lidarflow.predict import offsets
from lidarflow.scan import BeamGeometry, GridSpec, rasterize_batch, subcell_batch

pytestmark = [
    pytest.mark.skipif(not compiled.available(), reason="numba is not installed"),
    pytest.mark.usefixtures("compile_now"),
]

FULL = BeamGeometry(720, -math.pi, 2 * math.pi / 720, 0.05, 8.0)  # 360 degrees, seam included
PARTIAL = BeamGeometry(300, 1.0, -0.01, 0.05, 8.0)  # 172 degrees, sweeping clockwise
LONE = BeamGeometry(1, 0.0, 0.0, 0.05, 8.0)
FAR = BeamGeometry(720, -math.pi, 2 * math.pi / 720, 0.0, 1.7e308)  # beyond float32
GRIDS = [GridSpec(), GridSpec(50, 51, 0.33), GridSpec(7, 3, 2.0)]


def reference(function: Callable[..., Any], *args: Any) -> Any:
    """``function(*args)`` with the compiled kernels off (the NumPy references)."""
    numba = compiled.numba
    compiled.numba = None
    try:
        return function(*args)
    finally:
        compiled.numba = numba


@cache
def sample() -> tuple[np.ndarray, BeamGeometry]:
    from lidarflow.data import read_bag, sample_bag_path

    scans = list(read_bag(sample_bag_path()))
    return np.stack([s.ranges for s in scans]), scans[0].geometry


def edge_cases(geometry: BeamGeometry, dtype: type) -> np.ndarray:
    """Scans of ``geometry``: random returns, then all no return (inf), all NaN, all at
    range_max (a ring scan), every other at it, all 0, some -inf, all just under range_max."""
    rng = np.random.default_rng(geometry.count)
    top = dtype(geometry.range_max) if geometry.range_max < 1e30 else dtype(8.0)
    x = rng.uniform(0.0, 9.0, (12, geometry.count)).astype(dtype)
    x[1], x[2], x[3], x[4, ::2], x[5] = np.inf, np.nan, top, top, 0.0
    x[6, ::3], x[7] = -np.inf, top - dtype(0.01)
    x[8, ::5] = np.nan
    return x


def assert_same(got: Any, expected: Any) -> None:
    for g, e in zip(got, expected, strict=True) if isinstance(got, tuple) else [(got, expected)]:
        assert g.shape == e.shape and g.dtype == e.dtype
        np.testing.assert_array_equal(g, e)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("grid", GRIDS)
def test_the_sample_rasterises_as_numpy_does(dtype, grid):
    ranges, geometry = sample()
    ranges = ranges.astype(dtype)
    assert_same(
        rasterize_batch(ranges, geometry, grid), reference(rasterize_batch, ranges, geometry, grid)
    )
    assert_same(
        subcell_batch(ranges, geometry, grid), reference(subcell_batch, ranges, geometry, grid)
    )


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize(
    "geometry", [FULL, PARTIAL, LONE, FAR], ids=["360", "partial", "lone", "far"]
)
@pytest.mark.parametrize("grid", GRIDS)
def test_edge_cases_rasterise_as_numpy_does(dtype, geometry, grid):
    x = edge_cases(geometry, dtype)
    for ranges in (x, x[:, ::-1], x[3:4]):  # a strided batch, and one scan alone
        assert_same(
            rasterize_batch(ranges, geometry, grid),
            reference(rasterize_batch, ranges, geometry, grid),
        )
        assert_same(
            subcell_batch(ranges, geometry, grid), reference(subcell_batch, ranges, geometry, grid)
        )
    occupancy, visibility = rasterize_batch(x, geometry, grid)
    assert not occupancy[1:3].any() and not visibility[2].any()  # no return, NaN
    assert geometry is FAR or not occupancy[3].any()  # a ring scan


def test_a_geometry_with_a_numpy_range_min_compares_as_numpy_does():
    low = float(np.float32(0.1)) + 1e-12  # rounds down to float32: a reading there differs
    ranges = np.full((1, 300), np.float32(0.1))
    for range_min in (low, np.float64(low)):
        geometry = BeamGeometry(300, 1.0, -0.01, range_min, 8.0)
        expected = reference(rasterize_batch, ranges, geometry, GridSpec(20, 20, 0.01))
        assert_same(rasterize_batch(ranges, geometry, GridSpec(20, 20, 0.01)), expected)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_return_masks_are_numpy_s(dtype):
    ranges, geometry = sample()
    x = edge_cases(FULL, dtype)
    cases = [(ranges.astype(dtype), geometry.range_min, geometry.range_max), (x[0], 0.05, 8.0)]
    low = float(np.float32(0.1)) + 1e-12
    for limits in [(0.05, 8.0), (low, 8.0), (np.float64(low), 8.0), (0, 8), (0.0, 1.7e308)]:
        cases += [(x, *limits), (x.reshape(3, 4, -1), *limits), (x[:, ::2], *limits)]
    for r, range_min, range_max in cases:
        expected = beams._return_masks_numpy(r, range_min, range_max)
        assert_same(beams.return_masks(r, range_min, range_max), expected)


def test_counts_and_shifts_are_numpy_s():
    ranges, geometry = sample()
    occupancy, visibility = rasterize_batch(ranges, geometry)
    rng = np.random.default_rng(5)
    for k in range(1, len(occupancy), 3):
        last, now = occupancy[k - 1], occupancy[k]
        for radius in (0, 1, 3, 6):
            assert best_rigid_shift(last, now, radius) == reference(
                best_rigid_shift, last, now, radius
            )
        cut = (last[:37, 5:90], now[:37, 5:90], 3)
        assert best_rigid_shift(*cut) == reference(best_rigid_shift, *cut)
        predictions = [last, visibility[k - 1], rng.random(now.shape) < 0.3, np.roll(last, 1, 0)]
        args = (predictions, now, now != last)
        assert_same(
            offsets.counts_all_and_changed(*args), reference(offsets.counts_all_and_changed, *args)
        )
    empty = (np.zeros((4, 3)), np.zeros((4, 3)), 2)
    assert best_rigid_shift(*empty) == reference(best_rigid_shift, *empty) == (0, 0)


def test_a_predictor_on_the_sample_is_numpy_s():
    from lidarflow.data import read_bag, sample_bag_path
    from lidarflow.predict import Predictor

    scans = list(read_bag(sample_bag_path()))[:40]

    def run() -> list[np.ndarray]:
        predictor = Predictor(None, threads=1, online_decision=True)
        out = []
        for scan in scans:
            p = predictor.update(scan)
            out += [p.probability, p.occupied, p.occupancy, p.visibility]
        return out

    for got, expected in zip(run(), reference(run), strict=True):
        np.testing.assert_array_equal(got, expected)
