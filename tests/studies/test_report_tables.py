"""The studies that turn evaluation reports into tables: seeds, held-out, temporal average."""

import json

import pytest

from lidarflow.baselines import TA_THRESHOLD, TA_WINDOW
from studies import heldout_table, seed_table, ta_sweep, ta_verdicts
from studies.harness import VERDICTS


def test_seed_table_lays_runs_side_by_side(eval_reports, tmp_path):
    template = str(eval_reports / "eval_{}.json")
    argv = ["-o", str(tmp_path), "--run", f"s0={eval_reports}", "--run", f"s1={template}",
            "--recordings", "static", "dynamic", "missing"]  # fmt: skip
    table = seed_table.main(argv)

    assert list(table) == ["static", "dynamic"]  # a recording without reports is left out
    for by_run in table.values():
        assert by_run["s0"]["margins"] == by_run["s1"]["margins"]  # the same report twice
        assert by_run["s0"]["verdict"] in VERDICTS
        # the model's own rule (online) was judged, not the fixed offsets beside it
        assert set(by_run["s0"]["baselines"]) == {"copy_last", "temporal_average",
                                                  "constant_velocity", "tracker"}  # fmt: skip
    assert "| **recordings won** |" in (tmp_path / "seeds.md").read_text()
    assert json.loads((tmp_path / "seeds.json").read_text())["results"] == table


def test_seed_table_refuses_runs_without_reports(tmp_path):
    with pytest.raises(SystemExit):
        seed_table.main(["-o", str(tmp_path), "--run", f"s0={tmp_path}/eval_{{}}.json"])


def test_heldout_table_names_each_model_by_recording(eval_reports, tmp_path):
    reports = sorted(map(str, eval_reports.glob("eval_*.json")))
    study = heldout_table.main(["-o", str(tmp_path), *reports, "--name", "run=bundled"])

    # the model and its other decision rule, each a row per recording; no baseline is a row
    assert set(study) == {"bundled", "run_fixed"}
    assert set(study["bundled"]) == {"static", "dynamic"}
    assert "| bundled | **wins on" in (tmp_path / "heldout.md").read_text()


def test_ta_sweep_and_verdicts_judge_against_each_setting(sim_recordings, eval_reports, tmp_path):
    grid = ta_sweep.main(["-o", str(tmp_path / "sweep"), *map(str, sim_recordings),
                          "--windows", "3", "5", "--thresholds", "0.4"])  # fmt: skip
    assert set(grid["static"]) == {"copy_last", "3/0.4", "5/0.4"}
    for f1, changed in grid["dynamic"].values():
        assert 0.0 <= changed <= 1.0 and 0.0 < f1 <= 1.0
    # the default temporal average scored here is the one the evaluation scored
    report = json.loads((eval_reports / "eval_static.json").read_text())
    assert grid["static"][f"{TA_WINDOW}/{TA_THRESHOLD}"][0] == pytest.approx(
        report["recordings"][0]["methods"]["temporal_average"]["f1"]
    )

    reports = sorted(map(str, eval_reports.glob("eval_*.json")))
    sweep = str(tmp_path / "sweep" / "ta_sweep.json")
    table = ta_verdicts.main(["-o", str(tmp_path / "verdicts"), *reports, "--sweep", sweep,
                              "--settings", "3/0.4", "5/0.4"])  # fmt: skip
    assert set(table) == {"static", "dynamic"}
    assert all(len(row["5/0.4"]) == 2 for row in table.values())
    assert "| wins |" in (tmp_path / "verdicts" / "ta_verdicts.md").read_text()
