"""Rasterization: exact cell placement, visibility along beams, invalid beams, geometry."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lidarflow.beams import RETURN, beam_status, ring_band, ring_scans
from lidarflow.data import describe_recording
from lidarflow.errors import ScanError
from lidarflow.scan import (
    BeamGeometry,
    GridSpec,
    Scan,
    cell_centres,
    rasterize,
    rasterize_batch,
    subcell_batch,
)
from tests.conftest import make_recording

GRID = GridSpec(100, 100, 0.1)
SMALL = GridSpec(40, 40, 0.25)


def cell_of(x: float, y: float, grid: GridSpec) -> tuple[int, int] | None:
    r = math.floor(grid.height - x / grid.res)
    c = math.floor(grid.width / 2 - y / grid.res)
    return (r, c) if 0 <= r < grid.height and 0 <= c < grid.width else None


def one_beam_scan(theta: float, rho: float, n: int = 721) -> tuple[np.ndarray, BeamGeometry, int]:
    """A 360-degree scan in which only the beam nearest ``theta`` returns."""
    inc = 2 * math.pi / n
    geom = BeamGeometry(n, -math.pi, inc, 0.05, 20.0)
    k = round((theta + math.pi) / inc) % n
    ranges = np.full(n, np.nan)
    ranges[k] = rho
    return ranges, geom, k


def test_cell_centres_follow_design_convention():
    x, y = cell_centres(GRID)
    assert x[0, 0] == pytest.approx(9.95) and y[0, 0] == pytest.approx(4.95)
    assert x[99, 49] == pytest.approx(0.05) and y[99, 49] == pytest.approx(0.05)
    assert y[99, 50] == pytest.approx(-0.05)


def test_known_cell_straight_ahead_and_to_the_left():
    geom = BeamGeometry(2, 0.0, math.pi / 2, 0.05, 10.0)
    occ, vis = rasterize(Scan(np.array([5.0, 2.0]), geom), GRID)
    # (5, 0) -> r = floor(100 - 50) = 50, c = floor(50 - 0) = 50; (0, 2) lies on x = 0: row 100,
    # just outside the map (the map covers x in [0, 10) but floor(100 - 0) = 100).
    assert np.argwhere(occ).tolist() == [[50, 50]]
    assert vis[50, 50] and vis[60, 50] and not vis[40, 50]


@settings(max_examples=200, deadline=None)
@given(
    theta=st.floats(-math.pi, math.pi, allow_nan=False),
    rho=st.floats(0.06, 14.0, allow_nan=False),
)
def test_single_return_lands_in_the_cell_containing_its_point(theta, rho):
    ranges, geom, k = one_beam_scan(theta, rho)
    angle = geom.angle_min + k * geom.angle_increment
    occ, vis = rasterize(Scan(ranges, geom), GRID)
    expected = cell_of(rho * math.cos(angle), rho * math.sin(angle), GRID)
    got = [tuple(rc) for rc in np.argwhere(occ).tolist()]
    assert got == ([expected] if expected else [])
    assert not (occ & ~vis).any()


@settings(max_examples=60, deadline=None)
@given(rho=st.floats(0.3, 9.0), half_fov=st.floats(0.3, math.pi), n=st.integers(50, 800))
def test_visible_exactly_in_front_of_a_ring_of_returns(rho, half_fov, n):
    inc = 2 * half_fov / (n - 1)
    geom = BeamGeometry(n, -half_fov, inc, 0.05, 10.0)
    occ, vis = rasterize(Scan(np.full(n, rho), geom), GRID)
    x, y = cell_centres(GRID)
    dist, bearing = np.hypot(x, y), np.arctan2(y, x)
    inside_fov = np.abs(bearing) <= half_fov + inc / 2 - 1e-9
    clearly_in = inside_fov & (np.abs(bearing) < half_fov)
    # Between the sensor and the return: visible; behind it: not (unless occupied).
    assert vis[clearly_in & (dist < rho)].all()
    assert not vis[~occ & (dist >= rho)].any()
    # Occupied implies visible; nothing outside the field of view is visible.
    assert vis[occ].all()
    assert not vis[~inside_fov & ~occ].any()


@settings(max_examples=60, deadline=None)
@given(
    lo=st.floats(-1.4, 1.2),
    width=st.floats(0.05, 0.6),
    n=st.integers(2, 200),
    range_max=st.floats(1.0, 12.0),
)
def test_nothing_outside_a_narrow_field_of_view_is_visible(lo, width, n, range_max):
    inc = width / (n - 1)
    geom = BeamGeometry(n, lo, inc, 0.05, range_max)
    occ, vis = rasterize(Scan(np.full(n, np.inf), geom), GRID)  # no returns: free to range_max
    x, y = cell_centres(GRID)
    bearing, dist = np.arctan2(y, x), np.hypot(x, y)
    covered = (bearing >= lo - inc / 2 - 1e-9) & (bearing <= lo + width + inc / 2 + 1e-9)
    assert not occ.any()
    assert not vis[~covered].any()
    strictly = (bearing > lo - inc / 2 + 1e-9) & (bearing < lo + width + inc / 2 - 1e-9)
    assert vis[strictly & (dist <= range_max - 1e-9)].all()
    assert not vis[dist > range_max + 1e-9].any()


@settings(max_examples=40, deadline=None)
@given(
    n=st.sampled_from([360, 720, 1440]),
    shift=st.integers(1, 5),
    seed=st.integers(0, 2**31 - 1),
)
def test_rotating_a_full_circle_scan_by_beam_steps_equals_rolling_its_ranges(n, shift, seed):
    rng = np.random.default_rng(seed)
    ranges = rng.uniform(0.5, 9.0, n)
    ranges[rng.random(n) < 0.1] = np.inf
    ranges[rng.random(n) < 0.05] = np.nan
    inc = 2 * math.pi / n
    # Beams along the axes put their points exactly on cell borders, where one ulp decides the
    # cell; they are made unknown so the comparison below can be exact.
    angles = -math.pi + shift * inc + inc * np.arange(n)
    on_border = (np.abs(np.sin(angles)) < 1e-9) | (np.abs(np.cos(angles)) < 1e-9)
    ranges[on_border] = np.nan
    rotated = Scan(ranges, BeamGeometry(n, -math.pi + shift * inc, inc, 0.05, 10.0))
    rolled = Scan(np.roll(ranges, shift), BeamGeometry(n, -math.pi, inc, 0.05, 10.0))
    occ_a, vis_a = rasterize(rotated, GRID)
    occ_b, vis_b = rasterize(rolled, GRID)
    assert np.array_equal(occ_a, occ_b)
    assert np.array_equal(vis_a, vis_b)


def test_rotation_by_one_step_moves_occupied_cells_with_the_points():
    n = 360
    inc = 2 * math.pi / n
    ranges = np.linspace(2.0, 6.0, n)
    base = BeamGeometry(n, -math.pi, inc, 0.05, 10.0)
    turned = BeamGeometry(n, -math.pi + inc, inc, 0.05, 10.0)
    occ, _ = rasterize(Scan(ranges, turned), GRID)
    angles = turned.angles
    expected = {
        cell_of(r * math.cos(a), r * math.sin(a), GRID) for r, a in zip(ranges, angles, strict=True)
    } - {None}
    assert {tuple(rc) for rc in np.argwhere(occ).tolist()} == expected
    occ0, _ = rasterize(Scan(ranges, base), GRID)
    assert not np.array_equal(occ0, occ)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(3, 400))
def test_negative_increment_is_the_same_scan_reversed(seed, n):
    rng = np.random.default_rng(seed)
    ranges = rng.uniform(0.1, 12.0, n)
    ranges[rng.random(n) < 0.2] = np.inf
    lo, inc = -2.3, 4.6 / (n - 1)
    forward = Scan(ranges, BeamGeometry(n, lo, inc, 0.05, 11.0))
    backward = Scan(ranges[::-1].copy(), BeamGeometry(n, lo + (n - 1) * inc, -inc, 0.05, 11.0))
    (oa, va), (ob, vb) = rasterize(forward, GRID), rasterize(backward, GRID)
    # Beam angles differ by float rounding between the two descriptions: a point or a cell
    # bearing exactly on a border may fall either way, so allow a few border cells.
    assert np.count_nonzero(oa != ob) <= 2
    assert np.count_nonzero(va != vb) <= 4


def test_invalid_beams_follow_the_design_notes():
    n = 7
    geom = BeamGeometry(n, -0.3, 0.1, 0.5, 6.0)
    ranges = np.array([np.nan, -np.inf, 0.0, 0.2, np.inf, 9.0, 3.0])
    occ, vis = rasterize(Scan(ranges, geom), SMALL)
    x, y = cell_centres(SMALL)
    bearing, dist = np.arctan2(y, x), np.hypot(x, y)
    beam = np.rint((bearing - geom.angle_min) / geom.angle_increment)
    on = [(beam == k) & (np.abs(bearing - geom.angles[k]) < 0.05) & (dist > 0.5) for k in range(n)]
    for k in range(4):  # NaN, -inf, 0, below range_min: unknown
        assert not vis[on[k]].any(), k
    for k in (4, 5):  # +inf and beyond range_max: free out to range_max
        assert vis[on[k] & (dist <= 5.9)].all(), k
        assert not vis[on[k] & (dist > 6.0)].any(), k
    assert occ.sum() == 1  # only the 3 m return
    assert vis[on[6] & (dist < 2.9)].all() and not vis[on[6] & (dist > 3.2) & ~occ].any()


@settings(max_examples=40, deadline=None)
@given(
    range_max=st.floats(0.5, 9.0).map(lambda r: float(np.float32(r))),
    seed=st.integers(0, 2**16),
)
def test_no_return_written_as_range_max_reads_as_inf(range_max, seed):
    # Gazebo classic and SICK drivers write a beam that saw nothing as range_max (float32, as
    # a message stores it); read as a return it draws a ring at range_max in every frame.
    rng = np.random.default_rng(seed)
    geom = BeamGeometry(360, -math.pi, 2 * math.pi / 360, 0.1, range_max)
    ranges = rng.uniform(0.2, range_max * 1.5, (3, 360)).astype(np.float32)
    # returns just under range_max read as no return in a scan that writes it (ring_band)
    ranges[ranges >= np.float32(range_max - ring_band(range_max))] = np.inf
    ringed = np.where(np.isinf(ranges), np.float32(range_max), ranges)
    got, want = rasterize_batch(ringed, geom, GRID), rasterize_batch(ranges, geom, GRID)
    assert np.array_equal(got[0], want[0]) and np.array_equal(got[1], want[1])
    assert np.array_equal(subcell_batch(ringed, geom, GRID), subcell_batch(ranges, geom, GRID))
    # the float32 just below range_max is still a return, where the grid reaches it
    below = np.full((1, 360), np.nextafter(np.float32(range_max), np.float32(0)))
    assert rasterize_batch(below, geom, GRID)[0].any()
    assert beam_status(below[0], 0.1, range_max).tolist() == [RETURN] * 360


def test_a_noisy_ring_under_range_max_reads_as_no_return_where_the_scan_writes_one():
    # Simulators that add noise to "no return" (range_max) and then clip leave half the ring
    # exactly at range_max and half just under it; read as returns, a flickering half-ring.
    rng = np.random.default_rng(7)
    geom = BeamGeometry(360, -math.pi, 2 * math.pi / 360, 0.1, 3.5)
    ranges = rng.uniform(0.5, 3.0, (4, 360)).astype(np.float32)
    nothing = rng.random(ranges.shape) < 0.4
    clean = np.where(nothing, np.inf, ranges).astype(np.float32)
    noise = rng.normal(0.0, 0.01, ranges.shape)
    noisy = np.where(nothing, np.minimum(3.5 + noise, 3.5), ranges).astype(np.float32)
    got, want = rasterize_batch(noisy, geom, GRID), rasterize_batch(clean, geom, GRID)
    assert np.array_equal(got[0], want[0]) and np.array_equal(got[1], want[1])
    # a scan with only two readings at range_max does not write no return that way: a return
    # 1 cm under range_max stays one
    few = np.full((1, 360), np.nan, np.float32)
    few[0, :3] = [3.5, 3.5, 3.49]
    assert beam_status(few, 0.1, 3.5)[0, :3].tolist() == [2, 2, 1]
    few[0, 3:5] = 3.5  # four, 1 % of its beams: it does
    assert beam_status(few, 0.1, 3.5)[0, 2] == 2


def test_the_ring_is_found_scan_by_scan():
    # one scan writes no return as range_max (4 of its beams), the next does not: its reading
    # 2 cm under range_max is a return, however many the other scan has
    rows = np.array([[5.0] * 4 + [4.98] + [1.0] * 95, [4.98] + [1.0] * 99], np.float32)
    status = beam_status(rows, 0.1, 5.0)
    assert status[0, :5].tolist() == [2] * 5 and status[1, 0] == 1
    rec = make_recording(n=2, beams=100)
    rec.ranges = rows.ravel()
    rec.range_max[:] = 5.0
    rec.range_min[:] = 0.1
    beams = describe_recording(rec)["beams"]
    assert beams["no_return"] == 5 and beams["at_range_max"] == 4
    assert beams["scans_no_return_as_range_max"] == 1


def test_a_range_max_beyond_float32_reads_quietly():
    # pointcloud_to_laserscan's default range_max is the largest double
    import warnings

    geom = BeamGeometry(100, -1.0, 0.02, 0.1, 1.7976931348623157e308)
    ranges = np.full(100, 3.0, np.float32)
    ranges[:30] = np.inf
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        occ, vis = rasterize(Scan(ranges, geom), GRID)
        status = beam_status(ranges, 0.1, geom.range_max)
    assert status[:30].tolist() == [2] * 30 and status[30:].tolist() == [1] * 70
    assert occ.sum() > 0 and vis.sum() > occ.sum()
    assert not ring_scans(ranges, geom.range_max)  # its +inf readings are not "at range_max"


def test_zero_is_unknown_even_where_range_min_is_zero():
    geom = BeamGeometry(3, -0.1, 0.1, 0.0, 8.0)
    assert beam_status(np.array([0.0, 2.0, np.inf]), 0.0, 8.0).tolist() == [0, 1, 2]
    occ, vis = rasterize(Scan(np.zeros(3), geom), GRID)
    assert not occ.any() and not vis.any()


def test_a_geometry_sweeping_more_than_a_turn_is_refused():
    # 720 beams 1 rad apart: an increment written in degrees (0.5) read as radians
    with pytest.raises(ScanError, match="more than a full turn"):
        BeamGeometry(720, -math.pi, 1.0, 0.1, 8.0)
    BeamGeometry(361, -math.pi, math.radians(1.0), 0.1, 8.0)  # -180..180 inclusive: fine
    BeamGeometry(360, math.pi, -2 * math.pi / 360, 0.1, 8.0)  # descending, one turn


def test_batch_equals_one_at_a_time():
    rng = np.random.default_rng(0)
    geom = BeamGeometry(512, -math.pi / 2, math.pi / 511, 0.02, 5.6)
    ranges = rng.uniform(0.0, 7.0, (6, 512))
    ranges[:, ::7] = np.nan
    occ, vis = rasterize_batch(ranges, geom, GRID)
    for i in range(6):
        o, v = rasterize(Scan(ranges[i], geom), GRID)
        assert np.array_equal(o, occ[i]) and np.array_equal(v, vis[i])


def test_wide_scan_is_cropped_to_the_map():
    geom = BeamGeometry(768, -2.356, 4.7 / 767, 0.03, 11.0)
    occ, vis = rasterize(Scan(np.full(768, 3.0), geom), GRID)
    assert occ.any() and vis.any()
    assert occ.shape == (100, 100)


@pytest.mark.parametrize(
    "make",
    [
        lambda: BeamGeometry(0, 0.0, 0.1, 0.1, 1.0),
        lambda: BeamGeometry(3, math.nan, 0.1, 0.1, 1.0),
        lambda: BeamGeometry(3, 0.0, 0.0, 0.1, 1.0),
        lambda: BeamGeometry(3, 0.0, 0.1, 2.0, 1.0),
        lambda: GridSpec(0, 10, 0.1),
        lambda: GridSpec(10, 10, -0.1),
        lambda: Scan(np.zeros(4), BeamGeometry(3, 0.0, 0.1, 0.1, 1.0)),
    ],
)
def test_bad_geometry_is_a_scan_error(make):
    with pytest.raises(ScanError):
        make()


def test_wrong_batch_shape_is_a_scan_error():
    geom = BeamGeometry(3, 0.0, 0.1, 0.1, 1.0)
    with pytest.raises(ScanError, match=r"\(N, 3\)"):
        rasterize_batch(np.zeros((2, 4)), geom)


# --- where the returns lie inside their cells (subcell_batch) ---------------------------------


def _subcell_by_fine_grid(ranges: np.ndarray, geom: BeamGeometry, grid: GridSpec) -> np.ndarray:
    """The definition, through a rasterization 4x finer: ``edge`` = occupied and no return in
    the inner 2 x 2 of the cell's 4 x 4 sub-cells; ``near`` = a neighbour's return in the row or
    column of sub-cells that touches the cell."""
    fine = GridSpec(grid.height * 4, grid.width * 4, grid.res / 4)
    occ = rasterize_batch(ranges, geom, fine)[0]
    n, h, w = len(occ), grid.height, grid.width
    blocks = occ.reshape(n, h, 4, w, 4)
    edge = blocks.any(axis=(2, 4)) & ~blocks[:, :, 1:3, :, 1:3].any(axis=(2, 4))
    near = np.zeros((n, h, w), dtype=bool)
    near[:, 1:] |= blocks[:, :-1, 3].any(-1)  # the sub-row of the cell above that touches it
    near[:, :-1] |= blocks[:, 1:, 0].any(-1)
    near[:, :, 1:] |= blocks[:, :, :, :-1, 3].any(-2)
    near[:, :, :-1] |= blocks[:, :, :, 1:, 0].any(-2)
    return np.stack([edge, near], axis=1)


def test_subcell_matches_its_definition_on_a_four_times_finer_grid():
    rng = np.random.default_rng(0)
    geom = BeamGeometry(541, -2.35, 4.7 / 540, 0.05, 12.0)
    ranges = rng.uniform(0.05, 11.0, size=(6, 541))
    ranges[:, ::7] = np.nan  # unknown beams give nothing
    ranges[:, 3::11] = np.inf  # nor do beams without a return
    got = subcell_batch(ranges, geom, GRID)
    assert got.shape == (6, 2, *GRID.shape) and got.dtype == bool
    np.testing.assert_array_equal(got, _subcell_by_fine_grid(ranges, geom, GRID))
    assert got[:, 0].any() and got[:, 1].any()


@settings(max_examples=60, deadline=None)
@given(
    theta=st.floats(-3.0, 3.0),
    rho=st.floats(0.1, 9.0),
)
def test_subcell_edge_cells_are_occupied_and_near_cells_touch_one(theta, rho):
    ranges, geom, _ = one_beam_scan(theta, rho)
    occ, _ = rasterize(Scan(ranges, geom), GRID)
    edge, near = subcell_batch(ranges[None], geom, GRID)[0]
    assert not (edge & ~occ).any()  # edge only where rasterize marks the return
    rows, cols = np.nonzero(near)
    for r, c in zip(rows, cols, strict=True):  # every near cell is a 4-neighbour of the return
        assert occ[max(r - 1, 0) : r + 2, c].any() or occ[r, max(c - 1, 0) : c + 2].any()
        assert not occ[r, c]  # one return: its own cell is not its neighbour


@pytest.mark.parametrize(
    ("x", "edge", "near_row"),
    [
        (5.05, False, None),  # the middle of row 49: no edge, no neighbour touched
        (5.01, True, 50),  # 1 cm short of row 49's near edge: row 50 (nearer the sensor)
        (5.09, True, 48),  # 1 cm short of its far edge: row 48
    ],
)
def test_subcell_of_a_return_along_the_beam(x, edge, near_row):
    # Straight ahead on a grid 101 wide, the beam runs down the middle of column 50.
    geom = BeamGeometry(1, 0.0, 0.0, 0.05, 10.0)
    features = subcell_batch(np.array([[x]]), geom, GridSpec(100, 101, 0.1))[0]
    assert bool(features[0, 49, 50]) is edge
    expected = np.zeros((100, 101), dtype=bool)
    if near_row is not None:
        expected[near_row, 50] = True
    np.testing.assert_array_equal(features[1], expected)


def test_subcell_checks_the_ranges_shape():
    with pytest.raises(ScanError, match="ranges must be"):
        subcell_batch(np.zeros((2, 3)), BeamGeometry(4, 0.0, 0.1, 0.05, 10.0), GRID)


def test_ranges_straight_from_a_message_are_taken():
    # rclpy gives LaserScan.ranges as array.array('f'); a ROS 1 message or a user a list
    import array

    geom = BeamGeometry(3, -0.1, 0.1, 0.05, 10.0)
    for ranges in (array.array("f", [5.0, 5.0, 5.0]), [5.0, 5.0, 5.0], (5.0, 5.0, 5.0)):
        occ, _ = rasterize(Scan(ranges, geom, 1), GridSpec(100, 100, 0.1))
        assert bool(occ[50, 50]) and Scan(ranges, geom).ranges.dtype == np.float32
    with pytest.raises(ScanError, match="ranges must be numbers"):
        Scan(["far", "near", "x"], geom)
