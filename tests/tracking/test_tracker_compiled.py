"""The tracker's compiled kernels against their NumPy references, to the bit (issue 55): the
background split, the clusters, the association and the tracks' shifted cells, alone on edge
cases and together on the bundled recording."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from lidarflow import compiled
from lidarflow.tracking import Tracker, Tracks, associate
from lidarflow.tracking.background import split
from lidarflow.tracking.clusters import clusters

pytestmark = [
    pytest.mark.skipif(not compiled.available(), reason="numba is not installed"),
    pytest.mark.usefixtures("compile_now"),
]


def _both(monkeypatch: pytest.MonkeyPatch, run: Callable[[], Any]) -> tuple[Any, Any]:
    """``run()`` compiled, then on the NumPy references."""
    got = run()
    with monkeypatch.context() as m:
        m.setattr(compiled, "numba", None)
        expected = run()
    return got, expected


def _same(got: Any, expected: Any) -> None:
    """Equal to the bit: arrays by dtype, shape, values and the signs of their zeros."""
    if isinstance(expected, list | tuple):
        assert type(got) is type(expected) and len(got) == len(expected)
        for g, e in zip(got, expected, strict=True):
            _same(g, e)
        return
    if not isinstance(expected, np.ndarray):
        assert got == expected
        return
    assert isinstance(got, np.ndarray)
    assert got.dtype == expected.dtype and got.shape == expected.shape
    np.testing.assert_array_equal(got, expected)
    if expected.dtype.kind == "f":
        np.testing.assert_array_equal(np.signbit(got), np.signbit(expected))


def _sample_frames(n: int) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """The bundled recording's first ``n`` scans rasterised, with a slow drive's motion (5 cm
    and half a degree a scan, in cells and radians) as the engine hands it on."""
    from lidarflow.data import read_bag, sample_bag_path
    from lidarflow.scan import rasterize

    scans = list(read_bag(sample_bag_path()))[:n]
    motion = np.array([0.5, 0.0, np.deg2rad(0.5)])
    return [(*rasterize(s), motion) for s in scans]


def _tracked(frames: list[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> list[list[Any]]:
    tracker, out = Tracker(res=0.1), []
    for occupancy, visibility, motion in frames:
        tracker.observe(occupancy, visibility, motion)
        tracks = tracker.tracks(8)
        inner = [x for t in tracker._tracks for x in (t.state, t.covariance, t.cells, t.missed)]
        seen = [x for state, cells in tracks.objects for x in (state, cells)]
        maps = [tracker.background, tracks.at(1), tracks.at(3), tracks.cells_at(5)]
        out.append(maps + inner + seen)
    return out


def test_the_tracker_on_the_bundled_recording_is_the_reference_to_the_bit(monkeypatch):
    frames = _sample_frames(80)
    got, expected = _both(monkeypatch, lambda: _tracked(frames))
    assert sum(len(e) > 4 for e in expected) > 40  # tracks on most frames
    _same(got, expected)


def _maps(kind: str, h: int = 30, w: int = 20) -> tuple[np.ndarray, ...]:
    """``(occupied, visible, background, seen)`` of a named case."""
    rng = np.random.default_rng(len(kind))
    occupied = rng.random((h, w)) < 0.2
    visible = occupied | (rng.random((h, w)) < 0.7)
    background = rng.choice([0.0, 0.1, 0.19, 0.2, 0.21, 0.5, 1.0], (h, w))
    seen = rng.random((h, w)) < 0.8
    if kind == "empty":
        occupied[:] = False
        visible[:] = False
    elif kind == "full":
        occupied[:] = visible[:] = True
    elif kind == "border":  # occupied along the edges only, quiet background inside
        occupied[:] = False
        occupied[[0, -1], :] = occupied[:, [0, -1]] = True
        visible |= occupied
    elif kind == "nan":  # NaN spreads through NumPy's maximum: those cells are not moving
        background[5, 5] = background[0, 3] = np.nan
        seen[5, 5] = seen[0, 3] = True
    elif kind == "unseen":  # a first frame beside new ground: most cells take their occupancy
        seen[:] = False
    return occupied, visible, background, seen


@pytest.mark.parametrize("kind", ["random", "empty", "full", "border", "nan", "unseen"])
@pytest.mark.parametrize("alpha, threshold", [(0.05, 0.2), (1.0, 1.0), (0.3, 0.21)])
def test_the_background_split_is_the_reference_to_the_bit(monkeypatch, kind, alpha, threshold):
    maps = _maps(kind)

    def run() -> list[Any]:
        occupied, visible, background, seen = (m.copy() for m in maps)
        out = split(occupied, visible, background, seen, alpha, threshold)
        return [*out, background, seen]  # the last two updated in place

    _same(*_both(monkeypatch, run))


def _masks() -> list[np.ndarray]:
    rng = np.random.default_rng(7)
    full, empty = np.ones((12, 9), bool), np.zeros((12, 9), bool)
    border = empty.copy()
    border[0, 0] = border[0, -1] = border[-1, 0] = border[-1, -1] = border[5, 0] = True
    dense = [rng.random((40, 25)) < p for p in (0.02, 0.1, 0.3, 0.6)]
    return [full, empty, border, np.ones((100, 100), bool), *dense]


# Not the whole 100 x 100 map (index 3) at a reach of 150 cells: the reference's offset loop
# over that reach takes minutes.
CASES = [(i, link) for i in range(8) for link in (0.0, 1.0, 1.5, 2.0, 5.0, 150.0)
         if not (i == 3 and link > 5)]  # fmt: skip


@pytest.mark.parametrize(("index", "link"), CASES)
def test_the_clusters_are_the_reference_to_the_bit(monkeypatch, index, link):
    mask = _masks()[index]
    got, expected = _both(monkeypatch, lambda: clusters(mask, link))
    _same(list(got[0]), list(expected[0]))
    _same(got[1], expected[1])


@pytest.mark.parametrize("seed", range(6))
def test_the_association_is_the_reference(monkeypatch, seed):
    rng = np.random.default_rng(seed)
    # coarse positions: many exact ties, and distances exactly at the gate
    predicted = rng.integers(0, 6, (rng.integers(0, 9), 2)).astype(np.float64)
    measured = rng.integers(0, 6, (rng.integers(0, 9), 2)).astype(np.float64)
    predicted[:2] += 0.5
    for gate in (1.0, 2.0, np.sqrt(2.0), 100.0):
        _same(*_both(monkeypatch, lambda g=gate: associate(predicted, measured, g)))


def _objects() -> list[tuple[np.ndarray, np.ndarray]]:
    rng = np.random.default_rng(2)
    cells = [rng.integers(0, 20, (n, 2)) for n in (0, 1, 6, 30)]
    velocities = [(0.5, -0.5), (1.5, 2.5), (-7.3, 0.49), (40.0, -3.0)]  # rint's halves to even
    return [(np.array([1.0, 2.0, *v]), c) for v, c in zip(velocities, cells, strict=True)]


@pytest.mark.parametrize("k", [0, 1, 2, 3, 8])
def test_the_shifted_cells_are_the_reference(monkeypatch, k):
    # fresh Tracks each time: they keep what they computed
    _same(*_both(monkeypatch, lambda: Tracks((20, 20), _objects(), None).cells_at(k)))
    _same(*_both(monkeypatch, lambda: Tracks((20, 20), [], None).cells_at(k)))


def test_the_shifted_cells_of_odd_objects_go_as_the_reference(monkeypatch):
    narrow = [(s, c.astype(np.int32)) for s, c in _objects()]  # summed in int32 by NumPy
    far = [(np.array([0.0, 0.0, 1e10, 0.0]), np.array([[3, 3]]))]  # beyond 2**31: reference
    for objects in (narrow, far, _objects() + far):
        _same(*_both(monkeypatch, lambda o=objects: Tracks((20, 20), o, None).cells_at(2)))


@pytest.mark.parametrize("speed, error", [(np.nan, ValueError), (1e300, OverflowError)])
def test_the_shifted_cells_fail_as_the_reference(monkeypatch, speed, error):
    objects = [(np.array([0.0, 0.0, speed, 0.0]), np.array([[3, 3]]))]
    for use_numpy in (False, True):
        with monkeypatch.context() as m, pytest.raises(error):
            if use_numpy:
                m.setattr(compiled, "numba", None)
            Tracks((20, 20), objects, None).cells_at(1)
