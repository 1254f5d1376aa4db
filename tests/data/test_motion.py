"""Tests of the per-frame ego motion from poses: convention, unknown poses, units."""

from __future__ import annotations

import numpy as np
import pytest

from lidarflow.data.motion import metres_to_cells, relative_motions
from lidarflow.sim.platform import compose, relative


def test_motions_compose_back_to_the_poses():
    rng = np.random.default_rng(0)
    poses = np.cumsum(rng.normal(0, 0.3, (12, 3)), axis=0)
    motions, known = relative_motions(poses)
    assert not known[0] and known[1:].all()
    pose = poses[0]
    for t in range(1, len(poses)):
        np.testing.assert_allclose(motions[t], relative(poses[t - 1], poses[t]), atol=1e-12)
        pose = compose(pose, motions[t])
        np.testing.assert_allclose(pose[:2], poses[t, :2], atol=1e-9)
        assert np.isclose(np.cos(pose[2] - poses[t, 2]), 1.0)


def test_unknown_poses_give_identity_and_a_flag():
    poses = np.array([[0, 0, 0], [1, 0, 0], [np.nan, np.nan, np.nan], [3, 0, 0], [4, 0, 0.0]])
    motions, known = relative_motions(poses)
    assert known.tolist() == [False, True, False, False, True]
    assert np.all(motions[~known] == 0)
    motions, known = relative_motions(None, 4)
    assert motions.shape == (4, 3) and not known.any()
    with pytest.raises(ValueError, match="poses must be"):
        relative_motions(np.zeros((3, 2)))


def test_yaw_wraps_and_metres_become_cells():
    motions, _ = relative_motions(np.array([[0, 0, 3.1], [0.5, 0, -3.1]]))
    assert motions[1, 2] == pytest.approx(2 * np.pi - 6.2)
    cells = metres_to_cells(np.array([[0.25, -0.1, 0.2]]), 0.05)
    np.testing.assert_allclose(cells, [[5.0, -2.0, 0.2]], rtol=1e-6)
    assert cells.dtype == np.float32
