"""The verdict-noise study on a short simulated recording: one evaluation, kept, and its table."""

from __future__ import annotations

import pytest

from lidarflow.sim import SimConfig, write_simulation
from studies import verdict_noise as study
from studies.harness import read_json


def test_each_margin_stands_beside_its_interval_and_an_evaluation_is_kept(tmp_path, monkeypatch):
    recording = tmp_path / "walkers.npz"
    write_simulation(recording, 40, 5, SimConfig(scenario="static"))
    monkeypatch.setattr(study, "development", lambda: [recording])
    out = tmp_path / "out"
    study.main(["-o", str(out)])
    row = read_json(out / "summary.json")["walkers"]
    assert row["horizon"] == 15  # the simulator's 15 Hz: 15 scans in a second
    for name in study.MARGINS:
        margin, interval = row[name]["margin"], row[name]["interval"]
        if margin is not None:
            assert interval[0] <= interval[1]
    f1 = row["f1"]
    cell = f"{f1['margin']:+.4f} ({f1['interval'][0]:+.4f}..{f1['interval'][1]:+.4f})"
    assert f"| walkers | 15 | {cell}" in (out / "summary.md").read_text()
    kept = (out / "walkers.json").stat().st_mtime_ns
    study.main(["-o", str(out)])  # the evaluation is kept, not run again
    assert (out / "walkers.json").stat().st_mtime_ns == kept


def test_the_folds_table_takes_the_model_one_step_ahead_and_the_combination_at_k(tmp_path):
    from studies.harness import write_json

    def verdict(margin, interval):
        keys = ("f1", "changed_f1", "mover_f1")
        return {f"{k}_margin": margin for k in keys} | {"intervals": dict.fromkeys(keys, interval)}

    combined = verdict(-0.5, [-1.0, 1.0])
    combined["mover_f1_horizon_margin"] = -0.02
    combined["intervals"]["mover_f1_horizon"] = [-0.05, 0.01]
    result = {
        "horizon": 8,
        "verdicts": {"model": verdict(0.01, [0.005, 0.02]), "model_combined": combined},
    }
    folders = [tmp_path / "s0", tmp_path / "s1"]
    for folder in folders:
        for name in ("general_tracking_moving_1", "positive_2", "positive_1"):
            write_json(folder / f"{name}.json", result)
        write_json(folder / "summary.json", {})
    rows = study.fold_table(folders)
    assert list(rows) == [  # the development recordings' order, each seed in turn
        "positive_1 s0", "positive_1 s1", "positive_2 s0", "positive_2 s1",
        "general_tracking_moving_1 s0", "general_tracking_moving_1 s1",
    ]  # fmt: skip
    row = rows["positive_1 s0"]
    assert row["f1"] == {"margin": 0.01, "interval": [0.005, 0.02]}  # the model's, k = 1
    assert row["mover_f1_horizon"] == {"margin": -0.02, "interval": [-0.05, 0.01]}  # combined, K
    assert row["wins"] is False
    assert "-0.0200 (-0.0500..+0.0100)* | loses |" in study.table(rows)


def test_the_legs_table_marks_where_the_interval_holds_the_targets_bound():
    legs = {"recall": [0.4, 0.3], "precision": [0.5, 0.2]}
    copy = {"recall": [0.4, 0.1], "precision": [0.5, 0.25]}
    spans = {
        "recall_ratio": [[0.9, 1.1], [2.0, 4.5]],
        "precision_margin": [[-0.1, 0.1], [-0.2, 0.01]],
    }
    result = {
        "legs": {"model": legs, "model_combined": legs, "copy_last": copy},
        "legs_intervals": {"model": spans, "model_combined": spans},
    }
    rows = study.legs_rows(result)
    assert rows["K"]["recall_ratio"]["value"] == pytest.approx(3.0)  # 0.3 / 0.1
    assert rows["K"]["precision_margin"]["value"] == pytest.approx(-0.05)
    text = study.legs_table({"positive_1 s0": rows})
    assert "| positive_1 s0 | k=1 | 1.00 (0.90..1.10) | +0.000 (-0.100..+0.100)* |" in text
    assert "| positive_1 s0 | K | 3.00 (2.00..4.50) | -0.050 (-0.200..+0.010)* |" in text
    assert study.legs_rows({"legs": {}}) is None
