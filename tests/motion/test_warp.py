"""The NumPy warps (the core install's, without PyTorch) give the torch ops' numbers."""

from __future__ import annotations

import numpy as np
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from lidarflow.motion.warp import rigid_moved, warp_map
from lidarflow.ops.rigid import rigid_warp
from lidarflow.ops.warp import warp


@settings(max_examples=30, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    size=st.tuples(st.integers(2, 12), st.integers(2, 12)),
    scale=st.floats(0.0, 6.0),
)
def test_warp_map_is_the_torch_warp(seed, size, scale):
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
def test_rigid_moved_is_the_torch_rigid_warp(seed, dx, dy, yaw, res):
    image = np.random.default_rng(seed).random((9, 10))
    motion = np.array([dx * res, dy * res, yaw])
    ours = rigid_moved(image, motion, res)
    theirs = rigid_warp(
        torch.from_numpy(image)[None, None], torch.from_numpy(motion)[None], res
    )[0, 0]
    np.testing.assert_allclose(ours, theirs.numpy(), atol=1e-9)


def test_a_forward_step_brings_the_map_one_row_closer():
    image = np.zeros((5, 4))
    image[1, 1] = 1.0
    moved = rigid_moved(image, np.array([1.0, 0.0, 0.0]))
    assert moved[2, 1] == 1.0 and moved.sum() == 1.0
    assert warp_map(image, np.zeros((2, 5, 4))).tolist() == image.tolist()


def _single_pass_warp(image: np.ndarray, flow: np.ndarray) -> np.ndarray:
    """The warp as it was before its corners were kept (the bit-exact reference)."""
    h, w = image.shape
    rows, cols = np.mgrid[0:h, 0:w].astype(np.float64)
    x, y = cols + flow[0], rows + flow[1]
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


def test_kept_corners_give_the_single_pass_warp_to_the_bit() -> None:
    rng = np.random.default_rng(3)
    image = rng.random((2, 12, 9))
    image[1] = image[1] > 0.8
    flow = rng.normal(0.0, 2.0, (2, 12, 9))
    assert np.array_equal(warp_map(image[0], flow), _single_pass_warp(image[0], flow))
    for motion in ([1.3, -0.4, 0.2], [0.0, 2.5, -0.05], [1.3, -0.4, 0.2]):  # the last one kept
        both = rigid_moved(image, np.array(motion))
        for k in range(2):
            alone = rigid_moved(image[k], np.array(motion))
            assert np.array_equal(both[k], alone)
    assert not rigid_moved(np.zeros((12, 9)), np.array([1.0, 0.0, 0.1])).any()


def test_a_sparse_map_moved_around_its_cells_is_the_dense_warp_to_the_bit() -> None:
    """A map with few occupied cells is moved cell by cell on a motion's first use and by the
    kept corners from its second on: the same numbers, at any size, motion and cell size."""
    import lidarflow.motion.warp as warp_module

    rng = np.random.default_rng(11)
    for _ in range(200):
        h, w = (int(v) for v in rng.integers(5, 90, 2))
        image = np.zeros((h, w))
        k = int(rng.integers(1, max(2, int(0.02 * h * w))))
        image.flat[rng.choice(h * w, k, replace=False)] = rng.choice([1.0, 0.3, 0.77], k)
        res = float(rng.choice([1.0, 0.1]))
        motion = np.array([rng.normal(0, 3) * res, rng.normal(0, 3) * res, rng.normal(0, 0.3)])
        first = rigid_moved(image, motion, res)  # cell by cell (a new motion)
        second = rigid_moved(image, motion, res)  # the corners built and kept
        dense = warp_module._sampled(
            image.reshape(1, -1),
            warp_module._build_corners((*map(float, motion), h, w, res)),  # type: ignore[arg-type]
            image.shape,
        )
        assert np.array_equal(first, dense) and np.array_equal(second, dense)
