import json

import pytest

from lidarflow.sim import SimConfig, write_simulation
from studies import mover_persistence


def test_a_superset_of_copy_last_finds_no_fewer_movers_and_a_subset_no_more(tmp_path):
    # long enough that a passer-by's cells are occupied in under 5 % of the frames
    static = tmp_path / "static.npz"
    write_simulation(static, 100, 7, SimConfig(scenario="static"))
    results = mover_persistence.main(["-o", str(tmp_path), str(static)])["static"]
    assert results["hold_two"]["recall"] >= results["copy_last"]["recall"]
    assert results["drop_new"]["recall"] <= results["copy_last"]["recall"]
    assert 0.0 < results["copy_last"]["f1"] < 1.0  # a region was found, not an empty one
    assert "| static |" in (tmp_path / "mover_persistence.md").read_text()
    assert json.loads((tmp_path / "mover_persistence.json").read_text())["results"]["static"]


def test_a_recording_that_cannot_be_read_is_one_line(tmp_path):
    broken = tmp_path / "broken.npz"
    broken.write_bytes(b"not a recording")
    with pytest.raises(SystemExit, match=r"broken\.npz: "):
        mover_persistence.main(["-o", str(tmp_path), str(broken)])
