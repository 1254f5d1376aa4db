import json

import numpy as np
from safetensors.numpy import load_file

from studies import peer_comparison
from tests.conftest import FLOW_MODEL


def test_every_model_trains_per_fold_and_the_table_scores_both_horizons(
    sim_recordings, tiny_training, tmp_path
):
    recordings = [str(r) for r in sim_recordings]
    for model in ("flownet", "head_only", "sogmp", "deeptracking"):  # head_only after flownet
        peer_comparison.main(
            ["train", "-o", str(tmp_path), "--model", model, "--flow-init", str(FLOW_MODEL),
             "--recordings", *recordings, "--jobs", "2", "--set", *tiny_training]
        )  # fmt: skip
    for model in ("flownet", "head_only", "sogmp", "deeptracking"):
        for held in ("static", "dynamic"):
            assert (tmp_path / model / held / "run" / "model.safetensors").exists(), model
    peer_comparison.main(
        ["evaluate", "-o", str(tmp_path), "--recordings", *recordings, "--horizon", "3",
         "--jobs", "2"]
    )
    peer_comparison.main(["table", "-o", str(tmp_path)])

    study = json.loads((tmp_path / "peer_comparison.json").read_text())
    assert set(study["folds"]) == {"static", "dynamic"}
    expected = {"copy_last", "temporal_average", "constant_velocity", "flownet",
                "flownet_noflow", "head_only", "sogmp", "deeptracking"}  # fmt: skip
    for fold in study["folds"].values():
        assert expected <= set(fold)
        for row in fold.values():
            assert row["K"] >= 2 and 0.0 <= row["f1_1"] <= 1.0 and 0.0 <= row["f1_K"] <= 1.0
    assert study["parameters"]["sogmp"] == 730_245
    assert set(study["wins"]) >= {"flownet", "flownet_noflow", "head_only", "sogmp", "deeptracking"}
    table = (tmp_path / "peer_comparison.md").read_text()
    assert "| **mean** | sogmp |" in table and "wins" in table


def test_zero_flow_sets_only_the_flow_head_to_zero(tmp_path):
    weights = load_file(str(FLOW_MODEL / "model.safetensors"))
    run = tmp_path / "run"
    run.mkdir()
    (run / "model.safetensors").write_bytes((FLOW_MODEL / "model.safetensors").read_bytes())
    (run / "model.json").write_text((FLOW_MODEL / "model.json").read_text())
    zeroed = load_file(
        str(peer_comparison.zero_flow(run, tmp_path / "noflow") / "model.safetensors")
    )
    changed = [k for k in weights if not np.array_equal(weights[k], zeroed[k])]
    assert changed and all(".conv_flow." in k for k in changed)
    assert all(not zeroed[k].any() for k in zeroed if ".conv_flow." in k)


def test_a_verdict_needs_both_margins():
    base = {"copy_last": {"f1_1": 0.9, "changed_f1_1": 0.1}}
    assert peer_comparison.verdict({"f1_1": 0.91, "changed_f1_1": 0.2}, base, "1") == "wins"
    assert peer_comparison.verdict({"f1_1": 0.89, "changed_f1_1": 0.2}, base, "1") == "loses F1"
    assert peer_comparison.verdict({"f1_1": 0.91, "changed_f1_1": 0.1}, base, "1") == (
        "loses changed F1"
    )
