"""Motion from the returns (point-to-line ICP): exact on ray-cast rooms in motion.py's
convention, sub-cell on simulated drives where the maps show no motion, and silent on a
platform standing still."""

from __future__ import annotations

import numpy as np
import pytest

from lidarflow.motion import icp, scanmatch
from lidarflow.motion.icp import Reference, align, fit, recording_points, scan_points
from lidarflow.motion.odometry import metres_to_cells, relative_motions
from lidarflow.motion.scanmatch import STILL_WINDOW, ScanOdometry, compose, scan_motions
from lidarflow.scan import BeamGeometry, GridSpec, Scan, rasterize
from lidarflow.sim import PeopleConfig, PlatformConfig, SimConfig, lidar_preset, simulate

# A 6 x 4 m room with a pillar, as segments (x0, y0, x1, y1) in metres.
ROOM = np.array(
    [
        [-2.0, -2.0, 4.0, -2.0], [4.0, -2.0, 4.0, 2.0], [4.0, 2.0, -2.0, 2.0],
        [-2.0, 2.0, -2.0, -2.0], [1.0, 0.5, 1.4, 0.5], [1.4, 0.5, 1.4, 0.9],
        [1.4, 0.9, 1.0, 0.9], [1.0, 0.9, 1.0, 0.5],
    ]
)  # fmt: skip
BEAMS = BeamGeometry(720, -np.pi, np.deg2rad(0.5), 0.05, 8.0)


def _scan_from(pose: tuple[float, float, float], geometry: BeamGeometry = BEAMS) -> Scan:
    """The ranges a sensor at ``pose`` (x, y, yaw in the room) reads: nearest segment hit."""
    x, y, yaw = pose
    angles = geometry.angles + yaw
    d = np.stack([np.cos(angles), np.sin(angles)], 1)[:, None, :]
    a, e = ROOM[None, :, :2], ROOM[None, :, 2:] - ROOM[None, :, :2]
    w = a - np.array([x, y])
    cross = d[..., 0] * e[..., 1] - d[..., 1] * e[..., 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (w[..., 0] * e[..., 1] - w[..., 1] * e[..., 0]) / cross
        u = (w[..., 0] * d[..., 1] - w[..., 1] * d[..., 0]) / cross
    hit = (np.abs(cross) > 1e-12) & (t > 0) & (u >= 0) & (u <= 1)
    ranges = np.where(hit, t, np.inf).min(axis=1)
    return Scan(ranges.astype(np.float32), geometry)


def _motion(a: tuple[float, float, float], b: tuple[float, float, float]) -> np.ndarray:
    return relative_motions(np.array([a, b]))[0][1]


def test_scan_points_keeps_returns_in_bearing_order_in_rep_103():
    geometry = BeamGeometry(5, np.pi / 2, -np.pi / 4, 0.1, 5.0)  # left to right
    ranges = np.array([1.0, np.nan, 2.0, np.inf, 0.05], np.float32)
    points = scan_points(Scan(ranges, geometry))
    # Returns at +90 degrees (1 m left) and 0 degrees (2 m ahead), ordered by bearing.
    np.testing.assert_allclose(points, [[2.0, 0.0], [0.0, 1.0]], atol=1e-6)


def test_scan_points_are_the_returns_the_rasterizer_draws():
    # a range_max of 5.6 is no float32: a reading stored as float32(5.6) is a driver's "no
    # return" to the maps, and must not be a point for the scan matcher
    g = BeamGeometry(3, -0.1, 0.1, 0.02, 5.6)
    ranges = np.array([5.6, 5.6, 2.0], np.float32)
    assert len(scan_points(Scan(ranges, g))) == 1
    occupied, _ = rasterize(Scan(ranges, g), GridSpec())
    assert occupied.sum() == 1


@pytest.mark.parametrize(
    "start, end",
    [
        ((0.0, 0.0, 0.0), (0.004, -0.003, np.deg2rad(0.2))),  # sub-cell: what the maps miss
        ((0.3, -0.5, 0.4), (0.45, -0.42, 0.45)),
        ((0.0, 0.0, 0.0), (-0.25, 0.15, -0.06)),
    ],
)
def test_a_rigid_motion_through_the_room_is_recovered_in_motion_py_convention(start, end):
    true = _motion(start, end)
    found = align(scan_points(_scan_from(end)), scan_points(_scan_from(start)))
    assert found is not None and found.inliers > 0.9
    np.testing.assert_allclose(found.motion[:2], true[:2], atol=2e-3)
    assert abs(found.motion[2] - true[2]) < np.deg2rad(0.05)


def test_a_guess_brings_a_motion_too_large_to_pair_from_standing_still():
    start, end = (0.0, 0.0, 0.0), (0.9, 0.4, 0.2)
    true = _motion(start, end)
    current, previous = scan_points(_scan_from(end)), scan_points(_scan_from(start))
    unguided = align(current, previous)
    assert unguided is None or np.abs(unguided.motion[:2] - true[:2]).max() > 0.05
    guided = align(current, previous, true + np.array([0.08, -0.06, 0.02]))
    assert guided is not None
    np.testing.assert_allclose(guided.motion, true, atol=2e-3)


def test_too_few_returns_or_nothing_in_common_gives_no_motion():
    previous = scan_points(_scan_from((0.0, 0.0, 0.0)))
    assert align(previous[:5], previous) is None
    assert align(previous + np.array([50.0, 0.0]), previous) is None
    with pytest.raises(ValueError, match="points"):
        align(previous[:, :1], previous)


def test_compose_takes_motions_in_turn():
    quarter = np.array([1.0, 0.0, np.pi / 2])
    np.testing.assert_allclose(compose([quarter, quarter]), [1.0, 1.0, np.pi], atol=1e-12)
    np.testing.assert_allclose(compose([]), [0.0, 0.0, 0.0])


def _slow_drive(frames: int = 60) -> tuple[np.ndarray, list[np.ndarray], np.ndarray]:
    """Maps, returns and true motions (cells) of a 15 Hz 360 degree scanner on a platform
    creeping at under 0.1 cells and 0.4 degrees a frame: what the maps alone cannot resolve."""
    config = SimConfig(
        scenario="dynamic",
        sensor=lidar_preset("rplidar", rate_hz=15.0, range_max=3.5),
        platform=PlatformConfig(
            max_speed=0.1, max_turn_rate=0.1, cruise=(0.05, 0.1), pause_prob=0.0
        ),
        episode_frames=frames,
    )
    rec = simulate(frames, seed=7, config=config)
    true = metres_to_cells(relative_motions(rec.poses)[0], 0.1)
    return rec.maps(GridSpec())[0], recording_points(rec), true


def test_returns_find_the_motion_of_a_drive_every_frame_and_within_a_fraction_of_a_cell():
    occupancy, points, true = _slow_drive()
    refined = scan_motions(occupancy, points)
    maps_only = scan_motions(occupancy)
    found = np.isfinite(refined[:, 0])
    assert found[STILL_WINDOW + 1 :].mean() > 0.9
    assert found.sum() > np.isfinite(maps_only[:, 0]).sum()
    error = np.abs(refined[found] - true[found])
    assert np.median(error[:, :2]) < 0.08 and np.median(error[:, 2]) < np.deg2rad(0.15)
    with pytest.raises(ValueError, match="frames"):
        scan_motions(occupancy, points[:-1])


def test_a_platform_standing_still_is_left_uncompensated_despite_range_noise():
    rng = np.random.default_rng(0)
    scan = _scan_from((0.2, -0.1, 0.3))
    odometry = ScanOdometry()
    reported = []
    for _ in range(3 * STILL_WINDOW):
        noisy = Scan(
            scan.ranges + rng.normal(0, 0.015, scan.ranges.shape).astype(np.float32), scan.geometry
        )
        occupancy = np.zeros((100, 100), bool)
        reported.append(odometry.update(occupancy, scan_points(noisy)))
    assert all(m is None for m in reported)


def test_where_the_maps_show_a_motion_the_refined_one_is_reported_at_once():
    odometry = ScanOdometry()
    poses = [(0.0, 0.0, 0.0), (0.33, 0.12, 0.04)]
    scans = [_scan_from(p, BeamGeometry(720, -np.pi, np.deg2rad(0.5), 0.05, 8.0)) for p in poses]
    maps = [rasterize(scan, GridSpec())[0] for scan in scans]
    odometry.observe(maps[0], scan_points(scans[0]))  # a frame whose motion came from a pose
    reported = odometry.update(maps[1], scan_points(scans[1]))
    assert reported is not None  # the window has not filled: this is the maps' match, refined
    true = metres_to_cells(_motion(*poses), 0.1)
    np.testing.assert_allclose(reported[:2], true[:2], atol=0.02)
    assert abs(reported[2] - true[2]) < np.deg2rad(0.05)


@pytest.mark.slow
def test_a_narrow_scanner_standing_still_among_people_is_not_taken_to_travel(monkeypatch):
    sensor = lidar_preset("hokuyo-urg", fov_deg=86.0, beams=245, rate_hz=5.0, range_max=3.5)
    config = SimConfig(
        scenario="static", sensor=sensor, people=PeopleConfig(count=8), episode_frames=80
    )
    rec = simulate(80, seed=1, config=config)
    occupancy, points = rec.maps(GridSpec())[0], recording_points(rec)
    assert np.isnan(scan_motions(occupancy, points)).all()
    # Travel alone is fooled here (one wall, people crossing): standing still fits as well.
    monkeypatch.setattr(scanmatch, "STILL_FIT", (-1.0, 0.0))
    assert np.isfinite(scan_motions(occupancy, points)[:, 0]).mean() > 0.3


def test_returns_in_any_order_align_the_same():
    start, end = (0.0, 0.0, 0.0), (0.2, -0.1, 0.05)
    current, previous = scan_points(_scan_from(end)), scan_points(_scan_from(start))
    shuffled = previous[np.random.default_rng(1).permutation(len(previous))]
    a, b = align(current, previous), align(current, shuffled)
    assert a is not None and b is not None
    np.testing.assert_allclose(a.motion, b.motion, atol=1e-9)


def test_scans_without_returns_give_no_motion_and_no_error():
    odometry = ScanOdometry()
    empty = scan_points(Scan(np.full(720, np.nan, np.float32), BEAMS))
    room = scan_points(_scan_from((0.0, 0.0, 0.0)))
    maps = np.zeros((100, 100), bool)
    assert empty.shape == (0, 2)
    for points in (room, empty, room, empty, empty, room):
        assert odometry.update(maps, points) is None
    assert fit(empty, room, np.zeros(3)) == (0.0, float("inf"))


def test_a_scanner_mounted_upside_down_sweeping_backwards_aligns_the_same():
    backwards = BeamGeometry(720, np.pi - np.deg2rad(0.5), -np.deg2rad(0.5), 0.05, 8.0)
    start, end = (0.0, 0.0, 0.0), (0.03, 0.01, np.deg2rad(0.4))
    current, previous = (scan_points(_scan_from(p, backwards)) for p in (end, start))
    found = align(current, previous)
    assert found is not None
    np.testing.assert_allclose(found.motion, _motion(start, end), atol=2e-3)


def test_a_reference_made_once_aligns_as_the_returns_do_and_can_be_reused():
    start, end = (0.0, 0.0, 0.0), (0.15, 0.05, -0.04)
    current, previous = scan_points(_scan_from(end)), scan_points(_scan_from(start))
    reference = Reference(previous)
    plain = align(current, previous)
    assert plain is not None
    for _ in range(2):  # nothing in it is changed by aligning to it
        again = align(current, reference)
        assert again is not None
        np.testing.assert_array_equal(again.motion, plain.motion)
        assert (again.inliers, again.rms) == (plain.inliers, plain.rms)
    np.testing.assert_allclose(plain.motion, _motion(start, end), atol=1e-3)
    assert fit(current, reference, plain.motion) == fit(current, previous, plain.motion)
    with pytest.raises(ValueError, match=r"\(N, 2\)"):
        Reference(previous[:, :1])


def test_pairing_wraps_around_the_bearings_of_a_reference_with_few_returns():
    # fewer returns than the window of candidates: every one is a candidate of every point
    few = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0], [0.7, 0.7]])
    reference = Reference(few)
    source = np.array([[0.98, 0.01], [-0.05, -0.97], [0.69, 0.72]])
    _, best, _ = reference.pair(source, np.zeros(3), gate=0.5)
    nearest = np.argmin(((source[:, None] - reference.points[None]) ** 2).sum(-1), axis=1)
    np.testing.assert_array_equal(best, nearest)


def test_the_gauss_newton_step_solves_the_damped_normal_equations():
    rng = np.random.default_rng(7)
    reference = Reference(scan_points(_scan_from((0.0, 0.0, 0.0))))
    paired = rng.choice(len(reference), 200, replace=False)
    p = reference.points[paired] + rng.normal(0, 0.02, (200, 2))
    motion = np.array([0.1, -0.2, 0.05])
    step = icp._gauss_newton_step(reference, p, paired, motion)
    # the same system written out plainly, solved by LAPACK
    n = reference.normal[paired]
    lever = p - motion[:2]
    jacobian = np.stack([n[:, 0], n[:, 1], n[:, 1] * lever[:, 0] - n[:, 0] * lever[:, 1]], 1)
    residual = ((p - reference.points[paired]) * n).sum(axis=1)
    hessian = jacobian.T @ jacobian
    hessian += (icp._DAMPING * np.trace(hessian) + 1e-12) * np.eye(3)
    np.testing.assert_allclose(step, -np.linalg.solve(hessian, jacobian.T @ residual), rtol=1e-9)
