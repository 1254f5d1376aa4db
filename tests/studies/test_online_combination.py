"""The online combination's study runs end to end on a short simulated recording: it scores the
model, the model combined and the model learning beside the baselines, keeps a recording's
result, and tables the margins as evaluate judges them."""

from __future__ import annotations

import json

from lidarflow.sim import SimConfig, write_simulation
from studies import online_combination


def test_the_study_scores_keeps_and_tables_a_recording(tmp_path):
    static = tmp_path / "static.npz"  # 15 Hz: K = 15 needs 10 + 15 + 1 frames at least
    write_simulation(static, 40, 7, SimConfig(scenario="static"))
    out = tmp_path / "oc"
    online_combination.main(["-o", str(out), "--recordings", str(static), "--learn"])
    summary = json.loads((out / "summary.json").read_text())
    result = summary[static.stem]
    assert {"model", "model_combined", "copy_last"} <= set(result["f1"])
    assert {"model_learning", "model_learning_combined"} <= set(result["f1"])
    assert result["learning"]["model_learning"]["frames"] > 0
    assert all(len(v) == 2 for v in result["mover_f1_tolerant"].values())  # k = 1 and K
    assert len(result["chosen"]) == result["horizon"]
    assert result["warm_up"]["model_combined"]["scored"] > 0
    kept = (out / f"{static.stem}.json").stat().st_mtime_ns
    online_combination.main(["-o", str(out), "--recordings", str(static)])  # read back, not rerun
    assert (out / f"{static.stem}.json").stat().st_mtime_ns == kept
    table = online_combination.table([out])
    assert "| model_combined | k=1 |" in table and "folds won" in table
