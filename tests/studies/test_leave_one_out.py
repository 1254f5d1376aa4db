import json

from studies import leave_one_out
from tests.conftest import FLOW_MODEL


def test_leave_one_out_trains_a_fold_per_recording_and_judges_it(
    sim_recordings, tiny_training, tmp_path
):
    variant = "tiny=blurred " + " ".join(tiny_training)
    argv = ["-o", str(tmp_path), "--recordings", *map(str, sim_recordings), "--variant", variant]
    study = leave_one_out.main(argv)

    assert list(study["tiny"]) == ["static", "dynamic"]
    for held, scores in study["tiny"].items():
        assert (tmp_path / "tiny" / held / "run" / "model.safetensors").exists()
        for metrics in (scores["model"], *scores["baselines"].values()):
            assert 0.0 <= metrics["f1"] <= 1.0
    written = json.loads((tmp_path / "leave_one_out.json").read_text())
    assert written["results"] == json.loads(json.dumps(study))
    assert written["config"]["command"].startswith("python -m studies.leave_one_out -o")
    table = (tmp_path / "leave_one_out.md").read_text()
    assert "| tiny | static |" in table and "wins on" in table


def test_leave_one_out_online_decision_and_reuse(sim_recordings, tiny_training, tmp_path):
    # the head recipe (on v8's flow network, fine-tuned from v8) decides online: both rules scored
    variant = f"head=head model.init={FLOW_MODEL} data.memories_from_stream=false "
    variant += " ".join(tiny_training)
    argv = ["-o", str(tmp_path), "--recordings", *map(str, sim_recordings), "--variant", variant,
            "--held-out", str(sim_recordings[0]), "--online-decision"]  # fmt: skip
    study = leave_one_out.main(argv)
    scores = study["head"]["static"]
    assert set(scores["other_rule"]) == {"f1", "changed_f1", "ap"}
    assert scores["other_rule"] != scores["model"]
    weights = tmp_path / "head" / "static" / "run" / "model.safetensors"
    trained_at = weights.stat().st_mtime_ns

    assert leave_one_out.main(argv) == study
    assert weights.stat().st_mtime_ns == trained_at  # a finished fold is not trained again
    assert not (tmp_path / "head" / "dynamic").exists()
