"""The NumPy geometry: the grid convention, rigid moves (against the torch ops, round trips),
one sampler and its kept rigid samplers (the torch warps' numbers, the sparse move to the bit)."""

from __future__ import annotations

import doctest

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

import lidarflow.geometry as geometry
from lidarflow.geometry import (
    FlowWarp,
    Sampler,
    cell_to_metric,
    metric_to_cell,
    rigid_moved,
    rigid_positions,
    rigid_sampler,
    transform_cells,
    warp_map,
)
from lidarflow.ops import rigid
from lidarflow.ops.warp import warp

motions = st.tuples(st.floats(-8.0, 8.0), st.floats(-8.0, 8.0), st.floats(-np.pi, np.pi))


def test_the_docstrings_examples_hold() -> None:
    assert doctest.testmod(geometry, raise_on_error=True).attempted >= 8


def test_cell_centres_follow_the_design_notes() -> None:
    # H = W = 100, res = 0.1: the map covers x in [0, 10), y in [-5, 5); the sensor at the
    # middle of the bottom edge, row 0 the far edge, column 0 the left edge.
    x, y = cell_to_metric(np.array([0, 99, 99, 99]), np.array([0, 0, 49, 50]), 100, 100, 0.1)
    np.testing.assert_allclose(x, [9.95, 0.05, 0.05, 0.05])
    np.testing.assert_allclose(y, [4.95, 4.95, 0.05, -0.05])
    # a return at (x, y) marks the cell floor(H - x / res), floor(W / 2 - y / res): the nearest
    # cell of metric_to_cell
    px, py = np.array([3.21, 0.01, 9.99]), np.array([-1.37, 4.99, -4.99])
    rows, cols = metric_to_cell(px, py, 100, 100, 0.1)
    np.testing.assert_array_equal(np.rint(rows), np.floor(100 - px / 0.1))
    np.testing.assert_array_equal(np.rint(cols), np.floor(50 - py / 0.1))


@settings(max_examples=50, deadline=None)
@given(h=st.integers(1, 60), w=st.integers(1, 60), res=st.sampled_from([1.0, 0.1, 0.05]))
def test_cell_to_metric_and_back_is_the_identity(h, w, res) -> None:
    rows, cols = np.indices((h, w))
    back = metric_to_cell(*cell_to_metric(rows, cols, h, w, res), h, w, res)
    np.testing.assert_allclose(back, (rows, cols), atol=1e-9)


@settings(max_examples=100, deadline=None)
@given(motion=motions, h=st.integers(2, 40), w=st.integers(2, 40), res=st.sampled_from([1, 0.1]))
def test_new_to_old_to_new_is_the_identity(motion, h, w, res) -> None:
    m = np.array(motion) * [res, res, 1.0]
    rows, cols = np.indices((h, w), dtype=np.float64)
    old = transform_cells(cols, rows, m, h, w, res)
    new = transform_cells(*old, m, h, w, res, inverse=True)
    np.testing.assert_allclose(new, (cols, rows), atol=1e-9)
    again = transform_cells(*transform_cells(cols, rows, m, h, w, res, True), m, h, w, res)
    np.testing.assert_allclose(again, (cols, rows), atol=1e-9)


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    h=st.integers(2, 30),
    w=st.integers(2, 30),
    res=st.sampled_from([1.0, 0.1]),
    inverse=st.booleans(),
)
def test_transform_cells_is_the_torch_ops(seed, h, w, res, inverse) -> None:
    """The same numbers as :func:`lidarflow.ops.rigid.transform_cells` on random motions."""
    rng = np.random.default_rng(seed)
    motions = rng.normal(0.0, [4.0 * res, 4.0 * res, 1.0], (5, 3))
    cols, rows = rng.uniform(-3, w + 3, (5, h, w)), rng.uniform(-3, h + 3, (5, h, w))
    t = [torch.from_numpy(a) for a in (cols, rows, motions)]
    theirs = rigid.transform_cells(*t, h, w, res, inverse)
    for k in range(5):
        ours = transform_cells(cols[k], rows[k], motions[k], h, w, res, inverse)
        for a, b in zip(ours, theirs, strict=True):
            np.testing.assert_allclose(a, b[k].numpy(), rtol=0, atol=1e-12)
    # motions given together: each motion's numbers alone, to the bit
    together = transform_cells(cols, rows, motions[:, None, None, :], h, w, res, inverse)
    alone = [transform_cells(cols[k], rows[k], motions[k], h, w, res, inverse) for k in range(5)]
    for i in range(2):
        assert np.array_equal(together[i], np.stack([a[i] for a in alone]))


def test_rigid_positions_is_the_torch_rigid_flow() -> None:
    motion = np.array([2.3, -1.1, 0.3])
    c, r = rigid_positions(motion, 7, 5)
    flow = rigid.rigid_flow(torch.from_numpy(motion)[None], 7, 5)[0].numpy()
    rows, cols = np.indices((7, 5))
    np.testing.assert_allclose(c - cols, flow[0], atol=1e-12)
    np.testing.assert_allclose(r - rows, flow[1], atol=1e-12)
    with pytest.raises(ValueError, match="motion must be"):
        rigid_positions(np.zeros(4), 7, 5)
    with pytest.raises(ValueError, match="motions must be"):
        transform_cells(np.zeros(3), np.zeros(3), np.zeros((2, 4)), 7, 5)


@settings(max_examples=30, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    size=st.tuples(st.integers(2, 12), st.integers(2, 12)),
    scale=st.floats(0.0, 6.0),
)
def test_warp_map_is_the_torch_warp(seed, size, scale) -> None:
    rng = np.random.default_rng(seed)
    image = rng.random(size)
    flow = rng.normal(0.0, scale, (2, *size))
    ours = warp_map(image, flow)
    theirs = warp(torch.from_numpy(image)[None, None], torch.from_numpy(flow)[None])[0, 0]
    np.testing.assert_allclose(ours, theirs.numpy(), atol=1e-9)


@settings(max_examples=30, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    dx=st.floats(-5.0, 5.0),
    dy=st.floats(-5.0, 5.0),
    yaw=st.floats(-0.5, 0.5),
    res=st.sampled_from([1.0, 0.1]),
)
def test_rigid_moved_is_the_torch_rigid_warp(seed, dx, dy, yaw, res) -> None:
    image = np.random.default_rng(seed).random((9, 10))
    motion = np.array([dx * res, dy * res, yaw])
    ours = rigid_moved(image, motion, res)
    theirs = rigid.rigid_warp(
        torch.from_numpy(image)[None, None], torch.from_numpy(motion)[None], res
    )[0, 0]
    np.testing.assert_allclose(ours, theirs.numpy(), atol=1e-9)


@pytest.mark.parametrize("motion", [(0.0, 0.0, 0.0), (2.5, -1.25, 0.1), (-7.0, 3.0, -0.4)])
def test_a_rigid_sampler_is_rigid_warp_in_float32(motion) -> None:
    maps = torch.rand(3, 17, 12)
    want = rigid.rigid_warp(maps[None], torch.tensor([motion]))[0].numpy()
    got = rigid_sampler(np.array(motion, np.float32), 17, 12)(maps.numpy())
    assert got.dtype == np.float32
    np.testing.assert_allclose(got, want, atol=1e-5)


def test_rigid_samplers_are_kept_by_motion_and_the_oldest_goes() -> None:
    first = rigid_sampler(np.array([1.0, 0.0, 0.0]), 8, 6)
    assert rigid_sampler(np.array([1.0, 0.0, 0.0]), 8, 6) is first
    assert rigid_sampler(np.array([1.0, 0.0, 0.0]), 8, 6, res=0.5) is not first
    for k in range(geometry._KEPT_MOTIONS):
        rigid_sampler(np.array([2.0 + k, 0.0, 0.0]), 8, 6)
    assert rigid_sampler(np.array([1.0, 0.0, 0.0]), 8, 6) is not first


def test_a_forward_step_brings_the_map_one_row_closer() -> None:
    image = np.zeros((5, 4))
    image[1, 1] = 1.0
    moved = rigid_moved(image, np.array([1.0, 0.0, 0.0]))
    assert moved[2, 1] == 1.0 and moved.sum() == 1.0
    assert warp_map(image, np.zeros((2, 5, 4))).tolist() == image.tolist()
    assert not rigid_moved(np.zeros((12, 9)), np.array([1.0, 0.0, 0.1])).any()


def _single_pass(image: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``image`` sampled at columns ``x``, rows ``y``, bilinear, written out in one pass (the
    bit-exact reference)."""
    h, w = image.shape
    x0, y0 = np.floor(x), np.floor(y)
    out = np.zeros_like(image)
    for dy in (0, 1):
        for dx in (0, 1):
            xi, yi = x0 + dx, y0 + dy
            weight = (1.0 - np.abs(x - xi)) * (1.0 - np.abs(y - yi))
            inside = (xi >= 0) & (xi <= w - 1) & (yi >= 0) & (yi <= h - 1)
            xi = np.clip(xi, 0, w - 1).astype(np.intp)
            yi = np.clip(yi, 0, h - 1).astype(np.intp)
            out += np.where(inside, weight * image[yi, xi], 0.0)
    return out


def test_the_sampler_is_the_single_pass_warp_to_the_bit() -> None:
    rng = np.random.default_rng(3)
    image = rng.random((2, 12, 9))
    image[1] = image[1] > 0.8
    flow = rng.normal(0.0, 2.0, (2, 12, 9))
    rows, cols = np.indices((12, 9), dtype=np.float64)
    want = _single_pass(image[0], cols + flow[0], rows + flow[1])
    assert np.array_equal(warp_map(image[0], flow), want)
    for motion in ([1.3, -0.4, 0.2], [0.0, 2.5, -0.05], [1.3, -0.4, 0.2]):  # the last one kept
        both = rigid_moved(image, np.array(motion))
        c, r = rigid_positions(np.array(motion), 12, 9)
        for k in range(2):
            assert np.array_equal(both[k], rigid_moved(image[k], np.array(motion)))
            assert np.array_equal(both[k], _single_pass(image[k], c, r))


def test_flow_warp_is_warp_map_and_follows_a_new_flow() -> None:
    rng = np.random.default_rng(0)
    image = rng.random((15, 11))
    flow_warp = FlowWarp()
    for flow in (rng.normal(0, 2, (2, 15, 11)), rng.normal(0, 2, (2, 15, 11))):
        for _ in range(2):
            assert np.array_equal(flow_warp(image, flow), warp_map(image, flow))
    with pytest.raises(ValueError, match="maps must be"):
        Sampler.from_flow(np.zeros((2, 4, 4)))(np.zeros((1, 4, 5)))
    with pytest.raises(ValueError, match="flow must be"):
        Sampler.from_flow(np.zeros((4, 4)))
    with pytest.raises(ValueError, match="cols and rows"):
        Sampler(np.zeros((4, 4)), np.zeros((4, 5)))


def test_a_sparse_map_moved_around_its_cells_is_the_dense_move_to_the_bit() -> None:
    """A map with few occupied cells is moved cell by cell on a motion's first use and by the
    kept sampler from its second on: the same numbers, at any size, motion and cell size."""
    rng = np.random.default_rng(11)
    for _ in range(200):
        h, w = (int(v) for v in rng.integers(5, 90, 2))
        image = np.zeros((h, w))
        k = int(rng.integers(1, max(2, int(0.02 * h * w))))
        image.flat[rng.choice(h * w, k, replace=False)] = rng.choice([1.0, 0.3, 0.77], k)
        res = float(rng.choice([1.0, 0.1]))
        motion = np.array([rng.normal(0, 3) * res, rng.normal(0, 3) * res, rng.normal(0, 0.3)])
        first = rigid_moved(image, motion, res)  # cell by cell (a new motion)
        second = rigid_moved(image, motion, res)  # the sampler built and kept
        dense = Sampler(*rigid_positions(motion, h, w, res))(image)
        assert np.array_equal(first, dense) and np.array_equal(second, dense)


@pytest.mark.usefixtures("compile_now")
@pytest.mark.parametrize("numba_off", [False, True])
def test_a_bool_map_moves_as_its_float64_copy_to_the_bit(numba_off, monkeypatch) -> None:
    """Bool maps are sampled as they are (a corner adds its weight or nothing): the same
    float64 numbers as their float64 copies, dense and sparse, one map or a stack, compiled or
    in NumPy."""
    if numba_off:
        monkeypatch.setattr(geometry, "ready", lambda *args, **kwargs: False)
    rng = np.random.default_rng(5)
    for share in (0.01, 0.3, 0.9):
        maps = rng.random((3, 31, 24)) < share
        for motion in ([0.4, -1.7, 0.2], [3.0, 0.5, -0.6], [0.0, 0.0, 0.0]):
            for image in (maps, maps[1]):
                got = rigid_moved(image, np.array(motion), 0.1)
                assert got.dtype == np.float64
                assert np.array_equal(got, rigid_moved(image.astype(np.float64), motion, 0.1))


def test_a_samplers_adjoint_is_its_transpose() -> None:
    """<S x, g> = <x, S^T g> for a rigid move, cells leaving the map included."""
    from lidarflow.geometry import Sampler, rigid_positions

    rng = np.random.default_rng(4)
    sampler = Sampler(*rigid_positions(np.array([2.3, -1.6, 0.2]), 13, 11))
    x, g = rng.random((13, 11)), rng.random((13, 11))
    assert np.sum(sampler(x) * g) == pytest.approx(np.sum(x * sampler.adjoint(g)), rel=1e-12)
