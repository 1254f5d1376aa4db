"""The studies of motion from scans and of int8 export."""

import json

from studies import int8_accuracy, scan_odometry


def test_scan_odometry_compares_matched_motion_with_poses(sim_recordings, tmp_path):
    results = scan_odometry.main(["-o", str(tmp_path), *map(str, sim_recordings)])

    driving = results["dynamic.npz"]
    assert driving["has_poses"] and driving["frames"] == 24
    for way in ("maps_only", "refined_on_returns"):
        assert 0.0 <= driving[way]["steps_with_motion"] <= 1.0
        # the simulator's odometry is exact: matched motions are close to it
        assert driving[way]["median_error_cells"] < 3.0
    written = json.loads((tmp_path / "motions.json").read_text())
    assert written["config"]["grid"]["res"] == 0.1
    assert "| dynamic.npz | yes | refined_on_returns |" in (tmp_path / "motions.md").read_text()


def test_int8_accuracy_scores_both_graphs(sim_recordings, tmp_path):
    static, dynamic = sim_recordings
    argv = ["-o", str(tmp_path), "--calibration", str(static), "--recordings", str(dynamic)]
    results = int8_accuracy.main(argv)

    row = results["dynamic.npz"]
    assert 0.0 <= row["max_probability_difference"] < 0.5
    for graph in ("float32", "int8"):
        assert 0.0 < row[graph]["f1"] <= 1.0
    # int8 costs little: F1 within a few hundredths of float32's
    assert abs(row["int8"]["f1"] - row["float32"]["f1"]) < 0.05
    assert (tmp_path / "int8_accuracy.md").read_text().count("| dynamic.npz |") == 1
