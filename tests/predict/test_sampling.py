"""The kept samplers against the warps they stand for (issue 46)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lidarflow.motion.warp import warp_map
from lidarflow.ops.rigid import rigid_warp
from lidarflow.predict.baselines import best_rigid_shift, shift_map
from lidarflow.predict.offsets import pair_counts
from lidarflow.predict.sampling import BilinearSampler, FlowWarp, RigidSamplers


@pytest.mark.parametrize("motion", [(0.0, 0.0, 0.0), (2.5, -1.25, 0.1), (-7.0, 3.0, -0.4)])
def test_a_rigid_sampler_is_rigid_warp(motion) -> None:
    maps = torch.rand(3, 17, 12)
    m = torch.tensor([motion])
    want = rigid_warp(maps[None], m)[0].numpy()
    got = RigidSamplers()(np.array(motion), 17, 12)(maps.numpy())
    np.testing.assert_allclose(got, want, atol=1e-5)


def test_samplers_are_kept_by_motion_and_the_oldest_goes() -> None:
    samplers = RigidSamplers(size=2)
    first = samplers(np.array([1.0, 0.0, 0.0]), 8, 6)
    assert samplers(np.array([1.0, 0.0, 0.0]), 8, 6) is first
    samplers(np.array([2.0, 0.0, 0.0]), 8, 6)
    samplers(np.array([3.0, 0.0, 0.0]), 8, 6)
    assert samplers(np.array([1.0, 0.0, 0.0]), 8, 6) is not first


def test_flow_warp_is_warp_map_and_follows_a_new_flow() -> None:
    rng = np.random.default_rng(0)
    image = rng.random((15, 11))
    warp = FlowWarp()
    for flow in (rng.normal(0, 2, (2, 15, 11)), rng.normal(0, 2, (2, 15, 11))):
        for _ in range(2):
            np.testing.assert_allclose(warp(image, flow), warp_map(image, flow), atol=1e-12)
    with pytest.raises(ValueError, match="maps must be"):
        BilinearSampler.from_flow(np.zeros((2, 4, 4)))(np.zeros((1, 4, 5)))


def test_best_rigid_shift_is_the_brute_force_one() -> None:
    rng = np.random.default_rng(2)
    for trial in range(200):
        previous = rng.random((int(rng.integers(3, 30)), int(rng.integers(3, 30)))) < 0.2
        moved = shift_map(previous, int(rng.integers(-4, 5)), int(rng.integers(-4, 5)))
        current = moved | (rng.random(previous.shape) < 0.05) if trial % 2 else moved
        best, key = (0, 0), (-1, 0)
        for d_row in range(-3, 4):
            for d_col in range(-3, 4):
                overlap = int(np.count_nonzero(shift_map(previous, d_col, d_row) & current))
                if (overlap, -(abs(d_col) + abs(d_row))) > key:
                    best, key = (d_col, d_row), (overlap, -(abs(d_col) + abs(d_row)))
        assert best_rigid_shift(previous, current) == best


def test_pair_counts_are_the_pair_by_pair_counts() -> None:
    rng = np.random.default_rng(3)
    a, b = np.round(np.arange(-4.8, 4.3, 0.3), 1), np.round(np.arange(-0.6, 3.1, 0.3), 1)
    need = np.round(rng.normal(0, 4, 2000), 1)  # ties with the offsets on purpose
    moved = rng.choice([0.0, 1.0, 0.5, 0.3], 2000)
    target = rng.random(2000) < 0.3
    tp, predicted, positives = pair_counts(need, moved, target, a, b)
    hit = moved * a[:, None, None] + (1.0 - moved) * b[None, :, None] >= need
    np.testing.assert_array_equal(tp, (hit & target).sum(-1))
    np.testing.assert_array_equal(predicted, hit.sum(-1))
    assert positives == target.sum()
