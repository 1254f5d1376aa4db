"""The scan matcher's compiled loops against their NumPy references: the previous scan made
ready (bearings to the last bit, as NumPy's SIMD arctan2 may round apart from the C library's)
and the correlative search to the bit (integers and choices exactly), a motion's fit to
the last bits of its RMS (scalar products and a running sum where NumPy multiplies matrices and
sums pairwise: 1e-12 m)."""

from __future__ import annotations

import numpy as np
import pytest

from lidarflow import compiled
from lidarflow.data import read_bag, sample_bag_path
from lidarflow.motion import correlative, correlative_loops, icp
from tests.motion.test_correlative import _cases

pytestmark = [
    pytest.mark.skipif(not compiled.available(), reason="numba is not installed"),
    pytest.mark.usefixtures("compile_now"),
]

_REFERENCE_FIELDS = ("points", "bearings", "normal", "has_normal", "_window_x", "_window_y")


@pytest.fixture(scope="module")
def sample_points() -> list[np.ndarray]:
    return [icp.scan_points(scan) for scan in list(read_bag(sample_bag_path()))[:24]]


def _point_sets(sample_points: list[np.ndarray]) -> list[np.ndarray]:
    rng = np.random.default_rng(55)
    shuffled = sample_points[3][rng.permutation(len(sample_points[3]))]
    arc = np.stack([np.cos(np.linspace(0, 1, 40)), np.sin(np.linspace(0, 1, 40))], axis=1)
    circle = np.stack([np.cos(np.linspace(0, 6.2, 90)), np.sin(np.linspace(0, 6.2, 90))], 1)
    repeated = np.repeat(sample_points[5][:30], 2, axis=0)  # equal bearings: the stable order
    few = [rng.normal(0, 2, (n, 2)) for n in (1, 2, 3)]
    return [*sample_points[:6], shuffled, arc * 3, circle, repeated, *few]


def test_reference_is_the_numpy_reference_to_the_bit(sample_points, monkeypatch):
    sets = _point_sets(sample_points)
    got = [icp.Reference(p) for p in sets]
    monkeypatch.setattr(compiled, "numba", None)
    expected = [icp.Reference(p) for p in sets]
    for g, e in zip(got, expected, strict=True):
        for field in _REFERENCE_FIELDS:
            assert getattr(g, field).dtype == getattr(e, field).dtype
            if field == "bearings":  # SIMD builds of NumPy round arctan2 apart from libm's
                np.testing.assert_array_max_ulp(g.bearings, e.bearings, maxulp=1)
            else:
                np.testing.assert_array_equal(getattr(g, field), getattr(e, field), field)


def test_an_empty_reference_is_the_numpy_one(monkeypatch):
    got = icp.Reference(np.zeros((0, 2)))
    monkeypatch.setattr(compiled, "numba", None)
    expected = icp.Reference(np.zeros((0, 2)))
    for field in _REFERENCE_FIELDS:
        np.testing.assert_array_equal(getattr(got, field), getattr(expected, field))


def test_fit_is_the_numpy_reference_to_the_last_bits(sample_points, monkeypatch):
    rng = np.random.default_rng(7)
    cases = [(sample_points[i], sample_points[i - j], rng.normal(0, s, 3))
             for i in range(4, 24) for j in (1, 4) for s in (0.0, 0.02, 0.3)]  # fmt: skip
    cases.append((sample_points[1], sample_points[0], np.array([50.0, 0.0, 0.0])))  # none pair
    got = [icp.fit(*case) for case in cases]
    monkeypatch.setattr(compiled, "numba", None)
    expected = [icp.fit(*case) for case in cases]
    assert any(e[1] == np.inf for e in expected) and sum(e[0] > 0.5 for e in expected) > 20
    for (share, rms), (share_e, rms_e) in zip(got, expected, strict=True):
        assert share == share_e
        if rms_e == np.inf:
            assert rms == np.inf
        else:
            np.testing.assert_allclose(rms, rms_e, rtol=0, atol=1e-12)


def test_align_keeps_its_motion_and_fits_to_the_last_bits(sample_points, monkeypatch):
    pairs = [(sample_points[i], sample_points[i - 2]) for i in range(2, 24)]
    guess = np.array([0.04, -0.03, 0.02])
    got = [icp.align(c, p, guess) for c, p in pairs]
    monkeypatch.setattr(compiled, "numba", None)
    expected = [icp.align(c, p, guess) for c, p in pairs]
    for g, e in zip(got, expected, strict=True):
        assert (g is None) == (e is None)
        if e is not None:
            np.testing.assert_allclose(g.motion, e.motion, rtol=0, atol=1e-12)
            assert g.inliers == e.inliers
            np.testing.assert_allclose(g.rms, e.rms, rtol=0, atol=1e-12)


def _map_pairs(sample_points: list[np.ndarray]) -> list[tuple[str, np.ndarray, np.ndarray]]:
    rng = np.random.default_rng(12)
    pairs = [(name, p, c) for name, p, c in _cases()]
    for i in (1, 7, 15):  # the sample's walls, moved and turned a little, with clutter
        world = np.zeros((100, 100), bool)
        cells = np.clip(np.rint(50 - sample_points[i] * 10).astype(int), 0, 99)
        world[cells[:, 0], cells[:, 1]] = True
        moved = np.roll(world, (i % 5 - 2, 3 - i % 7), axis=(0, 1))
        pairs.append((f"sample {i}", world, moved ^ (rng.random(world.shape) < 0.01)))
    odd = rng.random((37, 81)) < 0.05
    pairs.append(("odd shape", odd, np.roll(odd, 2, axis=1)))
    pairs.append(("a column view", odd[:, ::2], np.roll(odd, 1, axis=0)[:, ::2]))
    return pairs


def test_placements_are_the_numpy_ones_to_the_bit(sample_points):
    for name, previous, current in _map_pairs(sample_points):
        place = correlative._Placements(previous, current)
        plain, dilated, cells, counts = correlative_loops.placements_loop(
            previous, current, correlative._COS, correlative._SIN, correlative._PAD,
            correlative.BLOCK,
        )  # fmt: skip
        np.testing.assert_array_equal(plain, place.plain, err_msg=name)
        np.testing.assert_array_equal(dilated, place.dilated, err_msg=name)
        np.testing.assert_array_equal(cells, place.cells, err_msg=name)
        dead = (current.shape[0] + 3 * correlative._PAD) * place.width + correlative._PAD
        np.testing.assert_array_equal(counts, (place.cells != dead).sum(axis=1), err_msg=name)


@pytest.mark.parametrize("first_blocks", [1, correlative.FIRST_BLOCKS])
def test_correlate_is_the_numpy_search_exactly(sample_points, first_blocks, monkeypatch):
    monkeypatch.setattr(correlative, "FIRST_BLOCKS", first_blocks)
    pairs = _map_pairs(sample_points)
    got = [correlative.correlate(p, c) for _, p, c in pairs]
    monkeypatch.setattr(compiled, "numba", None)
    expected = [correlative.correlate(p, c) for _, p, c in pairs]
    assert got == expected
