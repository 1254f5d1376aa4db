"""The constant-velocity shift and the online decision's pair counts against their brute-force
counterparts."""

from __future__ import annotations

import numpy as np

from lidarflow.baselines import best_rigid_shift, shift_map
from lidarflow.predict.offsets import pair_counts


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
