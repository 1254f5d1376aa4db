"""The verdict-noise study on a short simulated recording: one evaluation, kept, and its table."""

from __future__ import annotations

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
