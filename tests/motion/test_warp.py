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
