"""The recording format: round trip, ragged scans, slicing, corrupt files, sequences."""

from __future__ import annotations

import numpy as np
import pytest

from lidarflow.data import (
    Recording,
    SequenceSet,
    describe_recording,
    load_recording,
    split_segments,
)
from lidarflow.errors import RecordingError
from lidarflow.scan import BeamGeometry, GridSpec, Scan, rasterize
from tests.conftest import make_recording
from tests.train.blobs import blob_recording


def test_save_load_round_trip(tmp_path):
    rec = make_recording(poses=True)
    rec.extras["flow_backward"] = np.ones((len(rec), 2, 4, 4), np.float16)
    back = load_recording(rec.save(tmp_path / "r"))
    assert (tmp_path / "r.npz").exists()
    for name in (
        "ranges",
        "offsets",
        "angle_min",
        "angle_increment",
        "range_min",
        "range_max",
        "stamps_ns",
        "poses",
    ):
        np.testing.assert_array_equal(getattr(back, name), getattr(rec, name))
    assert back.meta["source"] == "synthetic" and back.meta["format_version"] == 1
    np.testing.assert_array_equal(back.extras["flow_backward"], rec.extras["flow_backward"])


def test_changing_beam_count_mid_recording_is_rasterized_per_scan():
    g1 = BeamGeometry(181, -np.pi / 2, np.pi / 180, 0.05, 8.0)
    g2 = BeamGeometry(361, -np.pi / 2, np.pi / 360, 0.05, 8.0)
    scans = [Scan(np.full(181, 3.0), g1, i) for i in range(3)]
    scans += [Scan(np.full(361, 2.0), g2, 3 + i) for i in range(2)]
    rec = Recording.from_scans(scans)
    assert rec.geometry_runs() == [(0, 3), (3, 5)]
    occ, vis = rec.maps()
    for i, scan in enumerate(scans):
        o, v = rasterize(scan)
        assert np.array_equal(occ[i], o) and np.array_equal(vis[i], v)
    occ_part, _ = rec.maps(start=2, stop=4)
    assert np.array_equal(occ_part, occ[2:4])


def test_slice_keeps_frames_and_per_frame_extras():
    rec = make_recording(n=10, poses=True)
    rec.extras["moving"] = np.arange(10)
    rec.extras["constant"] = np.arange(3)
    part = rec.slice(4, 7)
    assert len(part) == 3
    np.testing.assert_array_equal(part.scan(0).ranges, rec.scan(4).ranges)
    np.testing.assert_array_equal(part.extras["moving"], [4, 5, 6])
    np.testing.assert_array_equal(part.extras["constant"], [0, 1, 2])


def test_corrupt_and_foreign_files(tmp_path):
    (tmp_path / "bad.npz").write_bytes(b"this is not a zip")
    with pytest.raises(RecordingError, match=r"not an \.npz archive"):
        load_recording(tmp_path / "bad.npz")
    np.savez(tmp_path / "other.npz", a=np.zeros(3))
    with pytest.raises(RecordingError, match="missing ranges"):
        load_recording(tmp_path / "other.npz")
    good = make_recording().save(tmp_path / "good.npz")
    data = good.read_bytes()
    (tmp_path / "cut.npz").write_bytes(data[: len(data) // 2])
    with pytest.raises(RecordingError, match="cut short"):
        load_recording(tmp_path / "cut.npz")


def test_out_of_range_frame():
    with pytest.raises(RecordingError, match="frame 30 is out of range"):
        make_recording(n=30).scan(30)


def test_describe_counts_invalid_beams_and_gaps():
    rec = make_recording(n=20, beams=50)
    rec.stamps_ns[10:] += 2_000_000_000  # a 2.1 s hole in a 10 Hz recording
    rec.ranges[0] = -np.inf
    rec.ranges[1] = 0.0
    rec.ranges[2] = np.float32(rec.range_max[0])  # a driver's "no return"
    rec.ranges[3] = np.float32(rec.range_min[0] / 2)  # too close to measure
    short = rec.ranges[3].size
    info = describe_recording(rec)
    assert info["scans"] == 20 and info["beams_per_scan"] == [50]
    assert info["gaps"] == [{"before_frame": 10, "seconds": 2.1}]
    beams = info["beams"]
    assert beams["neg_inf"] == 1 and beams["zero"] >= 1 and beams["at_range_max"] >= 1
    assert beams["below_range_min"] == short
    rec.range_min[:] = 0.0  # a driver that states no minimum, and writes invalid beams as 0
    beams = describe_recording(rec)["beams"]
    assert beams["below_range_min"] == 0 and beams["unknown"] >= beams["zero"] >= 1
    assert beams["returns"] + beams["no_return"] + beams["unknown"] == beams["total"]
    assert info["field_of_view_deg"] == [180.0]


def test_segments_split_at_gaps_and_sensor_changes():
    rec = make_recording(n=50)
    rec.stamps_ns[20:] += 300_000_000  # gap of 4 periods at 10 Hz: > 2.5
    rec.stamps_ns[35:] += 200_000_000  # gap of 3 periods
    assert split_segments(rec) == [(0, 20), (20, 35), (35, 50)]
    rec2 = make_recording(n=10)
    rec2.stamps_ns[5:] += 100_000_000  # 2 periods: not a gap
    assert split_segments(rec2) == [(0, 10)]


def test_a_beam_count_varying_over_one_field_of_view_is_one_sensor():
    # LD06-style: 440-470 beams a turn, the same 360 degrees; then the range limit changes
    scans = []
    for i, count in enumerate([450, 440, 470, 455, 460, 448, 452, 466]):
        inc = 2 * np.pi / count
        limit = 12.0 if i < 6 else 8.0
        geometry = BeamGeometry(count, -np.pi, inc, 0.02, limit)
        scans.append(Scan(np.full(count, 3.0), geometry, i * 100_000_000))
    rec = Recording.from_scans(scans)
    assert len(rec.geometry_runs()) == 8
    assert split_segments(rec) == [(0, 6), (6, 8)]
    # a field of view that narrows is another sensor setup
    narrow = BeamGeometry(181, -np.pi / 2, np.pi / 180, 0.02, 12.0)
    wide = BeamGeometry(361, -np.pi, np.pi / 180, 0.02, 12.0)
    setups = [wide, wide, narrow, narrow]
    rec = Recording.from_scans(
        [Scan(np.full(g.count, 3.0), g, i * 100_000_000) for i, g in enumerate(setups)]
    )
    assert split_segments(rec) == [(0, 2), (2, 4)]


def test_sequences_windows_and_dropped_frames():
    rec = make_recording(n=50)
    rec.stamps_ns[20:] += 300_000_000
    seqs = SequenceSet([rec, make_recording(n=45)], length=20, grid=GridSpec(16, 16, 0.5))
    # recording 1: segments of 20 and 30 -> 1 + 1 windows, 10 frames dropped; recording 2: 2 windows
    assert len(seqs) == 4
    assert seqs.report.frames == 95 and seqs.report.frames_dropped == 10 + 5
    item = seqs[0]
    assert item.shape == (20, 2, 16, 16) and item.dtype == np.float32
    assert set(np.unique(item)) <= {0.0, 1.0}
    assert "shorter than a sequence" not in " ".join(seqs.report.notes)


def test_recording_shorter_than_a_sequence():
    with pytest.raises(RecordingError, match="no sequence of 20 frames fits"):
        SequenceSet([make_recording(n=12)], length=20)


def test_long_geometry_runs_rasterize_in_batches_to_the_same_maps(monkeypatch):
    from lidarflow.data import recording as recording_module

    rec = make_recording(n=23)
    whole = rec.maps(GridSpec(40, 40, 0.2)), rec.subcell_maps(GridSpec(40, 40, 0.2))
    monkeypatch.setattr(recording_module, "_BATCH_FRAMES", 5)  # 23 frames: 5 batches
    batched = rec.maps(GridSpec(40, 40, 0.2), 2, 21), rec.subcell_maps(GridSpec(40, 40, 0.2), 2, 21)
    np.testing.assert_array_equal(batched[0][0], whole[0][0][2:21])
    np.testing.assert_array_equal(batched[0][1], whole[0][1][2:21])
    np.testing.assert_array_equal(batched[1], whole[1][2:21])


def test_every_kth_frame_is_a_slower_sensors_recording():
    rec = blob_recording(n=25, seed=3)
    rec.poses = np.arange(75, dtype=np.float64).reshape(25, 3)
    rec.extras["moving"] = np.arange(25) % 2 == 0  # per frame: kept frame by frame
    rec.extras["note"] = np.array(7)  # not per frame: kept
    rec.meta["clock_jumps"] = [{"before_frame": 10}]
    rec.meta["frame_rate_hz"] = round(rec.frame_rate, 3)
    slow = rec.every(3)
    assert len(slow) == 9
    assert np.array_equal(slow.stamps_ns, rec.stamps_ns[::3])
    assert np.array_equal(slow.poses, rec.poses[::3])
    for i in range(9):
        assert np.array_equal(slow.scan(i).ranges, rec.scan(3 * i).ranges)
        assert slow.geometry(i) == rec.geometry(3 * i)
    assert np.array_equal(slow.extras["moving"], rec.extras["moving"][::3])
    assert int(slow.extras["note"]) == 7
    # ground truth between consecutive frames does not hold three frames apart
    assert "flow_backward" in rec.extras and not any(k.startswith("flow_") for k in slow.extras)
    assert slow.meta["every"] == 3 and "clock_jumps" not in slow.meta
    assert slow.meta["frame_rate_hz"] == pytest.approx(rec.frame_rate / 3, rel=1e-3)
    assert slow.every(2).meta["every"] == 6
    assert rec.every(1).meta["every"] == 1 and len(rec.every(1)) == 25
    with pytest.raises(RecordingError, match="step"):
        rec.every(0)
