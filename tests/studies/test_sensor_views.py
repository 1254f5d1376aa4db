"""A recording as another sensor would have seen it (studies.sensor_views)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lidarflow.errors import RecordingError
from lidarflow.scan import BeamGeometry, Scan
from studies.sensor_views import SensorView, coarser, narrower, shorter
from tests.train.blobs import blob_recording


def _scan(count: int, angle_min: float, increment: float, seed: int = 0) -> Scan:
    ranges = np.random.default_rng(seed).uniform(0.2, 9.0, count).astype(np.float32)
    return Scan(ranges, BeamGeometry(count, angle_min, increment, 0.1, 8.0), 42)


def _bearings(scan: Scan) -> np.ndarray:
    g = scan.geometry
    angles = g.angle_min + g.angle_increment * np.arange(g.count)
    return (angles + np.pi) % (2 * np.pi) - np.pi


@settings(deadline=None, max_examples=60)
@given(
    count=st.integers(2, 720),
    start=st.floats(-math.pi, math.pi),
    fov=st.floats(1.0, 360.0),
    sign=st.sampled_from([1.0, -1.0]),
)
def test_a_narrower_view_keeps_exactly_the_beams_within_half_the_field_of_view(
    count, start, fov, sign
):
    scan = _scan(count, start, sign * 2 * math.pi / count)  # one full turn from anywhere
    cut = narrower(scan, fov)
    inside = np.abs(_bearings(scan)) <= math.radians(fov) / 2 + 1e-9
    if not inside.any():
        assert cut.geometry.count == 1 and np.isnan(cut.ranges[0])
        return
    assert cut.geometry.count == inside.sum()
    # the same beams, the same ranges, and each still where it pointed
    assert sorted(cut.ranges.tolist()) == sorted(scan.ranges[inside].tolist())
    assert np.all(np.abs(_bearings(cut)) <= math.radians(fov) / 2 + 1e-6)
    # each kept range (all distinct) still points where it did, modulo a turn
    where = dict(zip(scan.ranges.tolist(), _bearings(scan), strict=True))
    for r, bearing in zip(cut.ranges.tolist(), _bearings(cut), strict=True):
        turn = (bearing - where[r] + math.pi) % (2 * math.pi) - math.pi
        assert abs(turn) < 1e-6


def test_a_narrower_view_of_a_turn_that_wraps_joins_its_two_ends():
    # 0 .. 2 pi: straight ahead is both the first and the last beams
    scan = _scan(360, 0.0, math.radians(1.0))
    cut = narrower(scan, 20.0)
    assert cut.geometry.count == 21
    assert cut.geometry.angle_min == pytest.approx(math.radians(-10.0))
    expected = np.concatenate([scan.ranges[350:], scan.ranges[:11]])
    np.testing.assert_array_equal(cut.ranges, expected)


def test_a_narrower_view_keeps_the_edges_either_way_round_and_one_turn_only():
    # 1-degree beams from -10 to +10 degrees and back: the 20-degree view keeps all 21 beams
    ahead = _scan(21, math.radians(-10.0), math.radians(1.0))
    back = _scan(21, math.radians(10.0), math.radians(-1.0))
    assert narrower(ahead, 20.0).geometry.count == narrower(back, 20.0).geometry.count == 21
    # 361 beams from 0 to 2 pi inclusive: the last repeats the first and is left out
    scan = _scan(361, 0.0, math.radians(1.0))
    cut = narrower(scan, 6.0)
    expected = np.concatenate([scan.ranges[357:360], scan.ranges[:4]])
    np.testing.assert_array_equal(cut.ranges, expected)
    assert cut.geometry.angle_min == pytest.approx(math.radians(-3.0))


def test_a_shorter_view_turns_every_return_beyond_its_limit_into_no_return():
    ranges = np.array([0.5, 3.4, 3.6, 7.9, 8.0, np.nan, np.inf, 0.0], np.float32)
    scan = Scan(ranges, BeamGeometry(8, -1.0, 0.25, 0.1, 8.0), 7)
    cut = shorter(scan, 3.5)
    assert cut.geometry.range_max == 3.5 and cut.stamp_ns == 7
    np.testing.assert_array_equal(cut.ranges[:2], ranges[:2])
    assert np.all(np.isposinf(cut.ranges[2:5])) and np.isnan(cut.ranges[5])
    assert np.isposinf(cut.ranges[6]) and cut.ranges[7] == 0.0
    # a limit beyond the scanner's own changes nothing but the readings at its own limit
    far = shorter(scan, 20.0)
    assert far.geometry.range_max == 8.0
    np.testing.assert_array_equal(far.ranges[:4], ranges[:4])
    assert np.isposinf(far.ranges[4]) and np.isnan(far.ranges[5])
    # a limit within range_min leaves no valid reading: said, not a broken geometry
    with pytest.raises(RecordingError, match="range_min"):
        shorter(scan, 0.05)


@given(count=st.integers(1, 400), every=st.integers(1, 9))
def test_a_coarser_view_keeps_every_kth_beam_where_it_pointed(count, every):
    scan = _scan(count, -2.0, 0.01)
    cut = coarser(scan, every)
    np.testing.assert_array_equal(cut.ranges, scan.ranges[::every])
    np.testing.assert_allclose(_bearings(cut), _bearings(scan)[::every], atol=1e-9)


def test_views_parse_and_name_each_other():
    assert SensorView.parse("fov86") == SensorView(fov_deg=86.0)
    view = SensorView.parse("beams2+range3.5+rate2")
    assert view == SensorView(range_max=3.5, every_beam=2, every_scan=2)
    assert view.name == "range3.5+beams2+rate2"
    assert SensorView.parse(view.name) == view
    assert SensorView().name == "recorded" and SensorView.parse("recorded") == SensorView()
    for spec in ("range3.14159265", "fov86.5+beams3", "range1234567"):
        assert SensorView.parse(spec).name == spec
    assert SensorView.parse("beams1+rate1") == SensorView()
    with pytest.raises(RecordingError, match="whole numbers"):
        SensorView(every_beam=2.5)  # type: ignore[arg-type]
    for bad, why in [
        ("fov", "cannot read"),
        ("range3.5+zoom2", "cannot read"),
        ("beams2+beams3", "twice"),
        ("beams1.5", "whole number"),
        ("rate0", "whole number"),
        ("fov400", "field of view"),
        ("range0", "positive distance"),
        ("range3.5+", "cannot read"),
        ("beams2.5", "whole number"),
    ]:
        with pytest.raises(RecordingError, match=why):
            SensorView.parse(bad)


def test_a_recordings_view_changes_every_scan_and_keeps_poses_and_stamps():
    rec = blob_recording(n=21, seed=2)
    rec.poses = np.arange(63, dtype=np.float64).reshape(21, 3)
    rec.extras["note"] = np.array(5)  # not per frame: kept
    view = SensorView.parse("fov120+range2+beams3+rate2")
    seen = view.recording(rec)
    assert len(seen) == 11 and seen.meta["sensor_view"] == view.name
    np.testing.assert_array_equal(seen.stamps_ns, rec.stamps_ns[::2])
    np.testing.assert_array_equal(seen.poses, rec.poses[::2])
    for i in range(11):
        expected = coarser(shorter(narrower(rec.scan(2 * i), 120.0), 2.0), 3)
        np.testing.assert_array_equal(seen.scan(i).ranges, expected.ranges)
        assert seen.geometry(i) == expected.geometry
    # the simulator's ground truth was made for the scans as they were
    assert "flow_backward" in rec.extras and "flow_backward" not in seen.extras
    assert int(seen.extras["note"]) == 5
    # a view that changes nothing is the recording itself; one of rate alone is every()
    assert SensorView().recording(rec) is rec
    assert len(SensorView(every_scan=3).recording(rec)) == 7
