"""The studies of other sensors: real recordings cut down, simulated sensors, short clips, and
drivers that write no return as range_max."""

import json

import numpy as np

from lidarflow.data import load_recording
from studies import other_sensors, range_max_ring, sensor_sweep, short_clips
from studies.harness import VERDICTS


def test_other_sensors_judges_each_view_and_adds_up_runs(sim_recordings, tmp_path):
    static, dynamic = sim_recordings
    out = ["-o", str(tmp_path)]
    other_sensors.main([*out, "--fold", f"{static}=bundled", "--views", "recorded", "rate2"])
    results = other_sensors.main([*out, "--fold", f"{dynamic}=bundled", "--views", "fov86"])

    # the second run added to the first's summary
    assert set(results) == {"static", "dynamic"}
    assert set(results["static"]) == {"recorded", "rate2"}
    for by_view in results.values():
        for scores in by_view.values():
            assert scores["verdict"] in VERDICTS
            assert scores["model_path"] == "bundled"
    assert (tmp_path / "static__rate2.json").exists()
    table = (tmp_path / "other_sensors.md").read_text()
    assert table.splitlines()[0] == "| recording | recorded | fov86 | rate2 |"
    assert "| **won** |" in table


def test_short_clips_scores_the_first_frames(sim_recordings, tmp_path):
    static = sim_recordings[0]
    study = short_clips.main(["-o", str(tmp_path), "--frames", "16", "24",
                              "--fold", f"{static}=bundled"])  # fmt: skip
    assert list(study) == ["static/first 16", "static/first 24"]
    assert all(r["verdict"] in VERDICTS for r in study.values())
    # a shorter clip scores fewer frames: the scores differ
    assert study["static/first 16"]["model"] != study["static/first 24"]["model"]


def test_sensor_sweep_simulates_each_sensor_and_scenario(tmp_path):
    argv = ["-o", str(tmp_path), "--sensors", "360deg_15Hz_3.5m", "--frames", "16"]
    study = sensor_sweep.main(argv)
    assert set(study) == {"360deg_15Hz_3.5m/static", "360deg_15Hz_3.5m/dynamic"}
    # the bundled model compensates ego motion: copy_last_ego is reported beside it
    assert "copy_last_ego" in study["360deg_15Hz_3.5m/dynamic"]["references"]
    written = json.loads((tmp_path / "sensors.json").read_text())
    assert written["config"]["sensors"] == ["360deg_15Hz_3.5m"]
    assert "copy last ego (reference)" in (tmp_path / "sensors.md").read_text()

    blind = sensor_sweep.main([*argv, "--without-poses"])  # the recordings are reused
    assert (tmp_path / "sensors_noposes.json").exists()
    assert blind["360deg_15Hz_3.5m/static"]["verdict"] in VERDICTS


def test_range_max_ring_rewrites_no_return(tmp_path):
    argv = ["-o", str(tmp_path), "--sensors", "360deg_15Hz_3.5m", "--frames", "16"]
    study = range_max_ring.main(argv)
    row = study["360deg_15Hz_3.5m/dynamic"]
    assert 0.0 < row["no_return_share"] < 1.0
    assert row["inf"]["verdict"] in VERDICTS and row["range_max"]["verdict"] in VERDICTS
    ringed = load_recording(tmp_path / "360deg_15Hz_3.5m_dynamic_range_max.npz")
    assert not np.isposinf(ringed.ranges).any()
    assert "| 360deg_15Hz_3.5m/static |" in (tmp_path / "range_max_ring.md").read_text()


def test_the_40hz_scanner_is_there_but_not_swept(tmp_path):
    assert "270deg_40Hz_30m" not in sensor_sweep.SWEPT
    path = sensor_sweep.simulated(tmp_path / "fast.npz", "270deg_40Hz_30m", "static", 8, 505)
    recording = load_recording(path)
    assert np.median(np.diff(recording.stamps_ns)) == 25_000_000  # 40 Hz
    assert float(recording.range_max[0]) == 30.0
