"""Tests of the per-frame ego motion from poses: convention, unknown poses, units."""

from __future__ import annotations

import numpy as np
import pytest

from lidarflow.motion.odometry import (
    OdometryCheck,
    cells_in_new_frame,
    metres_to_cells,
    relative_motions,
)
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


@pytest.fixture(scope="module")
def driving_maps():
    from lidarflow.scan import GridSpec
    from lidarflow.sim import SimConfig, simulate

    grid = GridSpec(40, 40, 0.05)
    rec = simulate(60, seed=3, config=SimConfig(scenario="dynamic", episode_frames=100, grid=grid))
    return rec.maps(grid)[0], rec.poses, grid


def _trusted(check, occupancy, motions):
    return [check.update(occupancy[t], motions[t] if t else None) for t in range(len(occupancy))]


def test_odometry_check_trusts_true_odometry_and_drops_a_mirrored_one(driving_maps):
    occupancy, poses, grid = driving_maps
    true = metres_to_cells(relative_motions(poses)[0], grid.res)
    check = OdometryCheck()
    assert all(_trusted(check, occupancy, true))
    assert len(check._moved) >= check.min_steps  # the drive gave evidence, not only defaults
    assert sum(check._moved) > 1.3 * sum(check._still)
    assert check.jumps == 0  # no step of a real drive is taken for a jump of the poses
    # A pose source whose y axis points the other way turns every turn and sideways step around.
    mirrored = metres_to_cells(relative_motions(poses * np.array([1, -1, -1]))[0], grid.res)
    check = OdometryCheck()
    trusted = _trusted(check, occupancy, mirrored)
    assert trusted[0] and not trusted[-1]
    assert trusted.index(False) <= 45  # within the first ten steps that moved the map enough
    check.reset()
    assert check.trusted and check.update(occupancy[0], None)


def test_odometry_check_counts_no_evidence_while_nothing_moves(driving_maps):
    occupancy, _, _ = driving_maps
    check = OdometryCheck()
    wrong = np.array([0.2, -0.3, 0.001], np.float32)  # moves nothing by 1.5 cells: no evidence
    for t in range(20):
        assert check.update(occupancy[t], wrong if t else None)
    assert len(check._moved) == 0


def _reset_at(poses: np.ndarray, at: int) -> np.ndarray:
    """The poses of an odometry reset to the origin at frame ``at``."""
    from lidarflow.sim.platform import relative

    out = poses.copy()
    for t in range(at, len(poses)):
        out[t] = relative(poses[at], poses[t])
    assert np.allclose(out[at], 0) and not np.allclose(poses[at], 0)
    return out


def test_odometry_check_rejects_a_pose_jump_alone(driving_maps):
    occupancy, poses, grid = driving_maps
    true = metres_to_cells(relative_motions(poses)[0], grid.res)
    reset = metres_to_cells(relative_motions(_reset_at(poses, 30))[0], grid.res)
    assert np.abs(reset[30] - true[30]).max() > 5  # the step across the reset is far off
    check = OdometryCheck()
    trusted = _trusted(check, occupancy, reset)
    assert trusted.count(False) == 1 and not trusted[30] and check.jumps == 1
    np.testing.assert_allclose(check.stand_in(), true[-1], atol=1e-6)  # and on as before
    check = OdometryCheck()
    _trusted(check, occupancy[:30], reset[:30])
    assert not check.update(occupancy[30], reset[30]) and check.jumped
    np.testing.assert_allclose(check.stand_in(), true[29], atol=1e-6)  # the stand-in ...
    np.testing.assert_allclose(check.stand_in(3.0), 3 * true[29], atol=1e-5)  # ... per step
    # an accepted step two typical steps long leaves its motion per typical step
    check = OdometryCheck()
    _trusted(check, occupancy[:30], true[:30])
    assert check.update(occupancy[30], 2 * true[30], span=2.0)
    np.testing.assert_allclose(check.stand_in(), true[30], atol=1e-5)
    # A jump in the first step has nothing to be judged against and is taken; it does not
    # blind the check to the next one (the usual step is a median, not the largest).
    twice = metres_to_cells(relative_motions(_reset_at(_reset_at(poses, 1), 30))[0], grid.res)
    check = OdometryCheck()
    trusted = _trusted(check, occupancy, twice)
    assert trusted[1] and not trusted[30] and check.jumps == 1


def _seen_after(world: np.ndarray, motion: np.ndarray) -> np.ndarray:
    """``world`` (a map) as seen after the sensor moved by ``motion`` (cells, radians)."""
    h, w = world.shape
    rows, cols = np.nonzero(world)
    r2, c2 = cells_in_new_frame(rows, cols, motion, h, w)
    inside = (r2 >= 0) & (r2 < h) & (c2 >= 0) & (c2 < w)
    out = np.zeros((h, w), bool)
    out[r2[inside], c2[inside]] = True
    return out


_SLOW = np.array([1.0, 0.0, 0.0])


def _after_slow_steps(world: np.ndarray) -> OdometryCheck:
    """A check that has seen five one-cell steps past ``world``, ``world`` last."""
    check = OdometryCheck()
    for _ in range(5):
        check.update(world, None)
        check.update(_seen_after(world, _SLOW), _SLOW)
    check.update(world, None)
    return check


def test_a_fast_step_that_lines_the_world_up_is_no_jump():
    rng = np.random.default_rng(5)
    world = np.zeros((40, 40), bool)
    world[rng.integers(0, 40, 150), rng.integers(0, 40, 150)] = True
    fast = np.array([8.0, 3.0, 0.05])
    # the scans show the fast step: taken; they show the robot going on at its pace: a jump
    check = _after_slow_steps(world)
    assert check.update(_seen_after(world, fast), fast) and not check.jumped
    check = _after_slow_steps(world)
    assert not check.update(_seen_after(world, _SLOW), fast) and check.jumped


def test_a_long_step_in_time_may_move_far_and_a_sparse_scene_gives_no_verdict():
    world = np.zeros((40, 40), bool)
    world[5:35:3, 5:35:3] = True  # 100 cells
    far = np.array([30.0, 0.0, 0.0])  # off the grid
    # 30 cells in one typical step while the scans went on at one: a jump; over ten typical
    # steps of time (a gap) it is 3 cells a step, no outlier, and taken
    assert not _after_slow_steps(world).update(_seen_after(world, _SLOW), far)
    assert _after_slow_steps(world).update(_seen_after(world, _SLOW), far, span=10.0)
    # two cells seen: too few to tell a jump from a real step
    sparse = np.zeros((40, 40), bool)
    sparse[10, 10] = sparse[20, 20] = True
    check = _after_slow_steps(sparse)
    assert check.update(_seen_after(sparse, _SLOW), far) and not check.jumped


def test_a_jump_needs_the_continued_motion_to_explain_the_scans_twice_as_well():
    world = np.zeros((40, 40), bool)
    world[2:14:2, 4:36:3] = True  # 66 cells, each seen apart after either motion below
    far = np.array([10.0, 0.0, 0.0])  # an outlier against one-cell steps
    own, going_on = _seen_after(world, far), _seen_after(world, _SLOW)
    assert not (own & going_on).any()
    own_cells, on_cells = np.argwhere(own), np.argwhere(going_on)

    def judged_a_jump(own_hits: int, on_hits: int) -> bool:
        current = np.zeros_like(world)
        current[tuple(own_cells[:own_hits].T)] = True
        current[tuple(on_cells[:on_hits].T)] = True
        check = _after_slow_steps(world)
        check.update(current, far)
        return check.jumped

    # the continued motion must hit at least twice as often as the step's own, and 3 more
    assert judged_a_jump(10, 23) and not judged_a_jump(10, 22)
    assert judged_a_jump(0, 3) and not judged_a_jump(0, 2)


def test_checked_motion_stands_in_for_a_jump_with_the_last_motion(driving_maps):
    from lidarflow.motion.scanmatch import checked_motion

    occupancy, poses, grid = driving_maps
    true = metres_to_cells(relative_motions(poses)[0], grid.res)
    reset = metres_to_cells(relative_motions(_reset_at(poses, 30))[0], grid.res)
    check = OdometryCheck()
    for t in range(31):
        motion, trusted = checked_motion(check, None, occupancy[t], reset[t] if t else None, True)
    assert not trusted
    np.testing.assert_allclose(motion, true[29], atol=1e-6)
    check = OdometryCheck()  # the same jump across a step of two typical ones
    for t in range(31):
        motion, _ = checked_motion(
            check, None, occupancy[t], reset[t] if t else None, True, pace=0.5 if t == 30 else None
        )
    np.testing.assert_allclose(motion, 2 * true[29], atol=1e-5)
    # A motion the scans found that jumps (a match pulled off by the scene) is replaced alike.
    check = OdometryCheck()
    for t in range(31):
        motion, _ = checked_motion(check, None, occupancy[t], reset[t] if t else None, False)
    np.testing.assert_allclose(motion, true[29], atol=1e-6)


def test_cells_in_new_frame_is_rigid_transform_cells_inverse_rounded():
    import torch

    from lidarflow.motion.odometry import cells_in_new_frame
    from lidarflow.ops.rigid import transform_cells

    rng = np.random.default_rng(3)
    rows, cols = rng.integers(0, 40, 50), rng.integers(0, 30, 50)
    motion = np.array([2.3, -1.1, 0.07])
    r2, c2 = cells_in_new_frame(rows, cols, motion, 40, 30)
    tc, tr = transform_cells(
        torch.tensor(cols, dtype=torch.float64)[None, None],
        torch.tensor(rows, dtype=torch.float64)[None, None],
        torch.tensor(motion)[None],
        40,
        30,
        inverse=True,
    )
    np.testing.assert_array_equal(r2, np.rint(tr[0, 0].numpy()))
    np.testing.assert_array_equal(c2, np.rint(tc[0, 0].numpy()))
