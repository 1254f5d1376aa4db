import json

import pytest

from studies import mover_table


def _methods(model: float, copy: float, tracker: float | None = None) -> dict:
    def scores(f1: float, movers: bool = True) -> dict:
        out = {"f1": f1, "changed_f1": 0.1, "ap": 0.5}
        if movers:
            out |= {"mover_f1": f1 / 2, "mover_f1_tolerant": f1 / 4}
        return out

    methods = {"model": scores(model), "copy_last": scores(copy), "temporal_average": scores(0)}
    methods["copy_last_ego"] = scores(0.99)  # a reference: not the model
    if tracker is not None:
        methods["tracker"] = scores(tracker, movers=False)  # mover metric undefined
    return methods


def _fold(out, variant, rec, methods):
    path = out / variant / rec / "evaluation.json"
    path.parent.mkdir(parents=True)
    path.write_text(json.dumps({"recordings": [{"path": rec, "methods": methods}]}))


def test_the_table_reads_each_fold_and_means_what_is_defined(tmp_path):
    _fold(tmp_path, "w1", "a", _methods(0.8, 0.6, 0.7))
    _fold(tmp_path, "w1", "b", _methods(0.4, 0.2))
    _fold(tmp_path, "w10", "a", _methods(0.6, 0.6, 0.7))
    (tmp_path / "w10" / "b" / "run").mkdir(parents=True)  # an unfinished fold: left out
    results = mover_table.main(["-o", str(tmp_path), "--variant", "w1", "--variant", "w10"])

    assert results["folds"]["w1"]["a"]["model"] == {
        "f1": 0.8, "mover_f1": 0.4, "mover_f1_tolerant": 0.2,
    }  # fmt: skip
    assert list(results["folds"]["w10"]) == ["a"]
    # the means: over the folds both variants finished (a alone)
    assert results["common_folds"] == ["a"]
    assert results["means"]["w1"]["model"]["f1"] == pytest.approx(0.8)
    assert results["means"]["w10"]["model"]["f1"] == pytest.approx(0.6)
    text = (tmp_path / "mover_table.md").read_text()
    assert "| w1 | a | 0.800 | 0.400 | 0.200 | 0.600 | 0.300 | 0.150 | 0.700 | - | - |" in text
    assert "| w1 | **mean of 1** | 0.800 |" in text
    written = json.loads((tmp_path / "mover_table.json").read_text())
    assert written["results"]["means"]["w10"]["model"]["f1"] == 0.6


def test_the_means_skip_undefined_scores():
    folds = {
        "a": mover_table.fold_scores(_methods(0.8, 0.6, 0.7)),
        "b": mover_table.fold_scores(_methods(0.4, 0.2)),
    }
    means = mover_table.mean_scores(folds)
    assert means["model"]["f1"] == pytest.approx(0.6)
    assert means["model"]["mover_f1_tolerant"] == pytest.approx(0.15)
    assert means["copy_last"]["mover_f1"] == pytest.approx(0.2)
    assert means["tracker"] == {"f1": 0.7, "mover_f1": None, "mover_f1_tolerant": None}


def test_no_finished_fold_is_a_usage_error(tmp_path):
    with pytest.raises(SystemExit):
        mover_table.main(["-o", str(tmp_path), "--variant", "w1"])
