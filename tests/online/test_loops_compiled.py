"""The online combination's compiled loops against their NumPy references, to the bit: the
leader's counts, the stacking's active cells, design, quiet counts, decided grid, decision
counts and thresholds, the kept maps' quantising, and the leader's choice of a pair."""

from __future__ import annotations

import numpy as np
import pytest

from lidarflow import compiled
from lidarflow.online import loops, stacking
from lidarflow.online.combination import quantised
from lidarflow.online.leader import Arrived, Leader, score_counts

pytestmark = [
    pytest.mark.skipif(not compiled.available(), reason="numba is not installed"),
    pytest.mark.usefixtures("compile_now"),
]


def _both(monkeypatch, run):
    """``run()`` compiled, then with the NumPy references."""
    assert not compiled.background  # the loops compile on their first call: no reference
    got = run()
    with monkeypatch.context() as patch:
        patch.setattr(compiled, "numba", None)
        expected = run()
    return got, expected


def _assert_same(got, expected):
    for g, e in zip(got, expected, strict=True):
        assert np.asarray(g).dtype == np.asarray(e).dtype
        np.testing.assert_array_equal(g, e)


@pytest.mark.parametrize("shape", [(40, 30), (1, 1), (3, 7)])
@pytest.mark.parametrize("radius", [0, 1, 2, 3])
def test_the_leaders_counts_are_the_numpy_references(shape, radius, monkeypatch):
    rng = np.random.default_rng(radius)
    decided = rng.random((6, *shape)) < np.array([0.0, 0.02, 0.1, 0.5, 0.9, 1.0])[:, None, None]
    rare, region = rng.random(shape) < 0.6, rng.random(shape) < 0.3
    occupied = rng.random(shape) < 0.2
    before = occupied ^ (rng.random(shape) < 0.1)
    region[0, :] = occupied[0, :] = True  # true cells on the edge: the near ones clipped
    _assert_same(
        *_both(
            monkeypatch,
            lambda: score_counts(decided, rare, before, Arrived(occupied, region), radius),
        )
    )
    # a small region (the reference counts inside its bounding box), and none
    small = np.zeros(shape, bool)
    patch = small[shape[0] // 2 :, 1 : 2 + shape[1] // 3]
    patch[...] = rng.random(patch.shape) < 0.5
    for other in (small, np.zeros(shape, bool)):
        arrived = (decided, rare, before, Arrived(occupied, other), radius)
        _assert_same(*_both(monkeypatch, lambda some=arrived: score_counts(*some)))


def _quantised_maps(rng, experts=5, shape=(30, 20)):
    """Quantised maps, mostly quiet, with every level and the levels around the clip's."""
    maps = np.where(rng.random((experts, *shape)) < 0.1, rng.integers(0, 256, (experts, *shape)), 0)
    maps.reshape(experts, -1)[0, :256] = np.arange(256)
    return maps.astype(np.uint8)


def test_the_stacking_on_quantised_maps_is_the_numpy_reference(monkeypatch):
    """Learning and deciding: the active cells, the design, the quiet counts, the decided
    grid, the decision counts and the thresholds all take part."""

    def run():
        rng = np.random.default_rng(5)
        stack = stacking.HorizonStacking(5, prior=0)
        out = []
        for _ in range(12):
            maps, rare = _quantised_maps(rng), rng.random((30, 20)) < 0.8
            out.append(stack.learn(maps, rare, rng.random((30, 20)) < 0.05))
            out.extend(stack.decided(maps, rare))
            out.extend(stack.decided(maps.astype(np.float32) / 255, rare))
        return [*out, *stack.state().values()]

    _assert_same(*_both(monkeypatch, run))


def test_learning_from_quantised_maps_is_learning_from_what_they_stand_for():
    rng = np.random.default_rng(6)
    quantised_stack, float_stack = stacking.HorizonStacking(5), stacking.HorizonStacking(5)
    for _ in range(5):
        maps, rare = _quantised_maps(rng), rng.random((30, 20)) < 0.8
        occupied = rng.random((30, 20)) < 0.05
        a = quantised_stack.learn(maps, rare, occupied)
        b = float_stack.learn(maps.astype(np.float64) / 255.0, rare, occupied)
        np.testing.assert_array_equal(a, b)
    for key, value in quantised_stack.state().items():
        np.testing.assert_array_equal(value, float_stack.state()[key], err_msg=key)


@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.uint8])
def test_the_active_cells_are_the_numpy_references(dtype, monkeypatch):
    rng = np.random.default_rng(7)
    flat = (rng.random((4, 500)) * (rng.random((4, 500)) < 0.1) * 0.05).astype(np.float32)
    flat[1, :9] = np.nextafter(np.float32(0.02), np.float32([0, 1, 0, 1, 0, 1, 0, 1, 1]))
    flat = (flat * 5000).astype(np.uint8) if dtype == np.uint8 else flat.astype(dtype)
    level = np.uint8(5) if dtype == np.uint8 else flat.dtype.type(0.02)
    for array in (flat, np.asarray(np.broadcast_to(flat[:, None], (4, 2, 500)))[:, 0]):
        _assert_same(*_both(monkeypatch, lambda a=array: [stacking.active_cells(a, level)]))


def test_the_thresholds_are_the_numpy_references(monkeypatch):
    rng = np.random.default_rng(8)
    cases = [rng.random((2, 40)) * rng.integers(0, 50, (2, 40)) for _ in range(20)]
    cases += [np.zeros((2, 40)) + (np.arange(40) == 3), np.full((2, 5), 2.0)]  # ties
    frees = [rng.random(c.shape) * 100 for c in cases]
    for occupied, free in zip(cases, frees, strict=True):
        for weight in (0.0, 1.0, 2.5):
            args = (occupied, free, weight)
            _assert_same(*_both(monkeypatch, lambda a=args: [stacking.best_thresholds(*a)]))


def test_quantising_is_the_numpy_reference(monkeypatch):
    rng = np.random.default_rng(9)
    maps = (rng.random((5, 3, 20, 30)) * 1.4 - 0.2).astype(np.float32)
    levels = (np.arange(512, dtype=np.float32) / np.float32(511)).reshape(1, 16, 32)
    maps[0, 0, :16] = levels[0, :, :30]  # the halves between levels: rounded to even
    for k in range(maps.shape[1]):
        _assert_same(*_both(monkeypatch, lambda k=k: [quantised(maps[:, k])]))


@pytest.mark.parametrize("baselines", [(3, 4, 2), (), (1,)])
def test_the_leaders_choice_is_the_numpy_references(baselines, monkeypatch):
    """Counts of every size, ties among them (integers), and none at all."""
    rng = np.random.default_rng(len(baselines))
    for trial in range(60):
        leader = Leader(8, first=5, baselines=baselines)
        if trial % 3 == 0:
            leader._f1 = rng.integers(0, 4, leader._f1.shape).astype(np.float64)
            leader._tolerant = rng.integers(0, 4, leader._tolerant.shape).astype(np.float64)
        elif trial % 3 == 1:
            leader._f1 = rng.random(leader._f1.shape) * 1e3
            leader._tolerant = rng.random(leader._tolerant.shape) * 50
        got, expected = _both(monkeypatch, leader._best)
        assert got == expected


def test_the_first_best_of_a_grid_is_where_argmax_finds_it():
    # the choice both the thresholds and the leader's pair end in: the first of equals, the
    # first NaN, as np.argmax
    rng = np.random.default_rng(10)
    grids = [rng.integers(0, 3, (n, m)).astype(np.float64) for n, m in [(4, 5), (8, 8), (1, 6)]]
    grids += [np.zeros((3, 3)), np.full((2, 4), -np.inf), rng.random((5, 5))]
    with_nan = rng.random((6, 6))
    with_nan[[2, 4], [3, 1]] = np.nan
    grids.append(with_nan)
    for grid in grids:
        expected = np.unravel_index(np.argmax(grid), grid.shape)
        assert loops._first_best(grid) == tuple(int(i) for i in expected)
