"""Ray casting and the sensor model."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lidarflow.errors import SimError
from lidarflow.scan import BeamGeometry
from lidarflow.sim.lidar import NO_HIT, STATIC_ID, cast_rays, lidar_preset, measure

WALL = np.array([[3.0, -20.0, 3.0, 20.0]])  # a wall across x = 3 m


def test_ray_against_known_wall_returns_the_right_range():
    geom = BeamGeometry(181, -math.radians(60), math.radians(120) / 180, 0.05, 10.0)
    ranges, ids = cast_rays(np.zeros((1, 3)), geom, WALL)
    np.testing.assert_allclose(ranges[0], 3.0 / np.cos(geom.angles), rtol=1e-12)
    assert (ids == STATIC_ID).all()


def test_pose_moves_and_turns_the_sensor():
    geom = BeamGeometry(3, -0.1, 0.1, 0.05, 10.0)
    # Sensor at (1, 2) facing -y: the wall y = -1 is 3 m straight ahead.
    wall = np.array([[-10.0, -1.0, 10.0, -1.0]])
    ranges, _ = cast_rays(np.array([[1.0, 2.0, -math.pi / 2]]), geom, wall)
    assert ranges[0, 1] == pytest.approx(3.0)
    assert ranges[0, 0] == pytest.approx(3.0 / math.cos(0.1))


def test_circle_range_and_id_and_occlusion():
    geom = BeamGeometry(1, 0.0, 0.01, 0.05, 10.0)
    circles = np.array([[2.0, 0.0, 0.1], [np.nan, np.nan, np.nan]])
    ranges, ids = cast_rays(np.zeros((1, 3)), geom, WALL, circles, np.array([7, 8]))
    assert ranges[0, 0] == pytest.approx(1.9)
    assert ids[0, 0] == 7
    # The wall is nearer than the circle behind it.
    far = np.array([[4.0, 0.0, 0.1]])
    ranges, ids = cast_rays(np.zeros((1, 3)), geom, WALL, far, np.array([3]))
    assert ranges[0, 0] == pytest.approx(3.0) and ids[0, 0] == STATIC_ID


def test_nothing_in_reach_is_no_hit():
    geom = lidar_preset("tim561").geometry()
    ranges, ids = cast_rays(np.zeros((1, 3)), geom, np.array([[30.0, -5, 30.0, 5]]))
    assert np.isinf(ranges).all() and (ids == NO_HIT).all()


def test_full_circle_sees_behind_across_the_seam():
    geom = lidar_preset("rplidar").geometry()
    wall = np.array([[-2.0, -5.0, -2.0, 5.0]])  # behind the sensor, across +-180 degrees
    ranges, _ = cast_rays(np.zeros((1, 3)), geom, wall)
    back = np.abs(np.cos(geom.angles)) > 0.5
    expected = np.where(np.cos(geom.angles) < -1e-9, -2.0 / np.cos(geom.angles), np.inf)
    np.testing.assert_allclose(ranges[0][back], expected[back], rtol=1e-9)


def _brute_force(pose, geom, segments, circles):
    """Every beam against every object, no culling."""
    out = np.full(geom.count, np.inf)
    for b, a in enumerate(geom.angles):
        d = np.array([math.cos(a + pose[2]), math.sin(a + pose[2])])
        o = pose[:2]
        for x0, y0, x1, y1 in segments:
            p, e = np.array([x0, y0]) - o, np.array([x1 - x0, y1 - y0])
            den = d[0] * e[1] - d[1] * e[0]
            if abs(den) < 1e-12:
                continue
            t = (p[0] * e[1] - p[1] * e[0]) / den
            s = (p[0] * d[1] - p[1] * d[0]) / den
            if t > 0 and 0 <= s <= 1:
                out[b] = min(out[b], t)
        for cx, cy, r in circles:
            c = np.array([cx, cy]) - o
            proj = c @ d
            disc = r * r - (c @ c - proj * proj)
            if disc >= 0 and proj > 0 and c @ c > r * r:
                out[b] = min(out[b], proj - math.sqrt(disc))
    out[out > geom.range_max + 0.5] = np.inf
    return out


@settings(max_examples=25, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    preset=st.sampled_from(["tim561", "hokuyo-urg", "rplidar"]),
)
def test_culled_casting_matches_brute_force(seed, preset):
    rng = np.random.default_rng(seed)
    geom = lidar_preset(preset, beams=90).geometry()
    segments = rng.uniform(-8, 8, (12, 4))
    circles = np.column_stack([rng.uniform(-6, 6, (6, 2)), rng.uniform(0.05, 0.5, 6)])
    pose = np.array([rng.uniform(-1, 1), rng.uniform(-1, 1), rng.uniform(-math.pi, math.pi)])
    ranges, _ = cast_rays(pose[None], geom, segments, circles)
    expected = _brute_force(pose, geom, segments, circles)
    near = expected <= geom.range_max  # beyond range_max the culling may drop far hits
    np.testing.assert_allclose(ranges[0][near], expected[near], rtol=1e-9, atol=1e-9)
    assert np.all(ranges[0][~near] > geom.range_max)


@pytest.mark.parametrize(
    ("name", "beams", "fov", "rate", "range_max"),
    [
        ("tim561", 811, 270.0, 15.0, 10.0),
        ("hokuyo-urg", 512, 180.0, 10.0, 5.6),
        ("hokuyo-utm", 768, 270.0, 7.5, 11.0),
        ("rplidar", 360, 360.0, 10.0, 8.0),
    ],
)
def test_presets_have_the_right_beams(name, beams, fov, rate, range_max):
    cfg = lidar_preset(name)
    geom = cfg.geometry()
    assert geom.count == beams and cfg.rate_hz == rate and geom.range_max == range_max
    covered = math.degrees(geom.angle_increment * (beams if fov == 360 else beams - 1))
    assert covered == pytest.approx(fov)
    if fov < 360:
        assert math.degrees(geom.angle_min) == pytest.approx(-fov / 2)
    assert lidar_preset("tim561").geometry().angle_increment == pytest.approx(math.radians(1 / 3))


def test_unknown_preset_is_a_sim_error():
    with pytest.raises(SimError, match="unknown sensor preset"):
        lidar_preset("velodyne")


def test_measure_noise_dropouts_and_no_returns():
    cfg = lidar_preset("tim561", noise_std=0.02, dropout_prob=0.1, dropout_value="mixed")
    true = np.full((200, 811), 4.0)
    true[:, :10] = np.inf
    true[:, 10:20] = 12.0  # beyond range_max
    r = measure(true, cfg, np.random.default_rng(0))
    assert r.dtype == np.float32  # what recordings store
    r = r.astype(np.float64)
    kept = r[:, 20:]
    dropped = np.isnan(kept) | (kept == 0)
    assert 0.08 < dropped.mean() < 0.12
    assert np.isnan(kept).any() and (kept == 0).any()
    assert abs(kept[~dropped].std() - 0.02) < 0.002
    assert abs(kept[~dropped].mean() - 4.0) < 0.002
    head = r[:, :20]
    assert (np.isposinf(head) | np.isnan(head) | (head == 0)).all()
    assert np.isposinf(head).mean() > 0.85


def test_mixed_pixels_fall_between_the_surfaces():
    cfg = lidar_preset("tim561", noise_std=0.0, dropout_prob=0.0, mixed_pixel_prob=1.0)
    true = np.array([[2.0, 2.0, 6.0, 6.0]])
    r = measure(true, cfg, np.random.default_rng(1))
    assert 2.0 < r[0, 1] < 6.0
    assert r[0, 0] == 2.0 and r[0, 2] == 6.0 and r[0, 3] == 6.0
