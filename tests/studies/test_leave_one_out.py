import json

from studies import leave_one_out


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


def test_leave_one_out_reuses_finished_folds(sim_recordings, tiny_training, tmp_path):
    variant = "tiny=blurred " + " ".join(tiny_training)
    argv = ["-o", str(tmp_path), "--recordings", *map(str, sim_recordings), "--variant", variant]
    leave_one_out.main([*argv, "--held-out", str(sim_recordings[0])])
    weights = tmp_path / "tiny" / "static" / "run" / "model.safetensors"
    trained_at = weights.stat().st_mtime_ns

    again = leave_one_out.main([*argv, "--held-out", str(sim_recordings[0])])
    assert list(again["tiny"]) == ["static"]
    assert weights.stat().st_mtime_ns == trained_at  # not trained again
    assert not (tmp_path / "tiny" / "dynamic").exists()
