"""Choosing a model's fixed decision offset: the rule, and `lidarflow choose-offset`."""

from __future__ import annotations

import json

import pytest

from lidarflow.data import read_bag, sample_bag_path
from lidarflow.evaluate.offsets import choose_offset, decided_online, win_margin, with_offset
from lidarflow.models.presets import resolve_model
from tests.conftest import make_model_dir
from tests.test_cli import run

BASE = {
    "copy_last": {"f1": 0.90, "changed_f1": 0.0},
    "temporal_average": {"f1": 0.85, "changed_f1": 0.30},
    "constant_velocity": {"f1": 0.88, "changed_f1": 0.20},
}


def test_win_margin_is_the_smaller_lead_over_the_best_baselines():
    methods = {**BASE, "m": {"f1": 0.95, "changed_f1": 0.32}, "n": {"f1": 0.89, "changed_f1": 0.9}}
    assert win_margin(methods, "m") == pytest.approx(0.02)  # changed F1: 0.32 - 0.30
    assert win_margin(methods, "n") == pytest.approx(-0.01)  # F1: 0.89 - 0.90
    methods["m"]["changed_f1"] = None  # nothing changed: counts as 0
    assert win_margin(methods, "m") == pytest.approx(-0.30)


def test_the_offset_with_the_largest_summed_margin_is_chosen():
    a = {"f1": 0.95, "changed_f1": 0.31}  # margin 0.01 on both
    one = {"methods": {**BASE, "a": a, "b": {"f1": 0.93, "changed_f1": 0.5}}}  # b: 0.03
    two = {"methods": {**BASE, "a": a, "b": {"f1": 0.80, "changed_f1": 0.5}}}  # b: -0.10
    best, totals = choose_offset([one], {0.0: "a", 0.6: "b"})
    assert best == 0.6 and totals == pytest.approx({0.0: 0.01, 0.6: 0.03})
    best, totals = choose_offset([one, two], {0.0: "a", 0.6: "b"})
    assert best == 0.0 and totals == pytest.approx({0.0: 0.02, 0.6: -0.07})


def test_candidates_decide_with_their_fixed_offset_only():
    card = {"model": "flownet", "model_kwargs": {"online_decision": True, "decision_offset": 1.2},
            "weights_path": "/x", "grid": {"height": 100}}  # fmt: skip
    copy = with_offset(card, 0.3)
    assert copy["model_kwargs"] == {} and "weights_path" not in copy  # decision keys dropped
    assert copy["decision"] == {"offset": 0.3, "online": False}
    assert card["model_kwargs"]["online_decision"] is True  # the original is not changed
    assert decided_online(card) and not decided_online(copy)
    assert with_offset(card, 1.0, online=True)["decision"] == {"offset": 1.0, "online": True}


@pytest.mark.slow
def test_choose_offset_writes_the_model_with_the_chosen_offset(tmp_path, capsys):
    model = make_model_dir(tmp_path / "head", occupancy_head=True)
    card = json.loads((model / "model.json").read_text())
    card["decision"] = {"offset": 0.0, "online": True}  # as the bundled model's
    (model / "model.json").write_text(json.dumps(card))
    rec = read_bag(sample_bag_path()).slice(0, 16).save(tmp_path / "r.npz")
    out = tmp_path / "tuned"
    argv = ["choose-offset", str(rec), "-m", str(model), "-o", str(out), "--warmup", "2",
            "--offset", "0", "--offset", "2", "--threads", "1"]  # fmt: skip
    code, text, err = run(argv, capsys)
    assert code == 0, err
    record = json.loads((out / "offsets.json").read_text())
    margins = record["summed_win_margin"]
    assert set(margins) == {"0", "2"} and record["chosen"] == float(max(margins, key=margins.get))
    assert f"decision offset {record['chosen']:g}" in text
    resolve_model(out)  # loads
    card = json.loads((out / "model.json").read_text())
    assert card["decision"] == {"offset": record["chosen"], "online": True}  # its own rule kept
    assert "decision_offset" not in card["model_kwargs"]  # the decision is not the model's
    assert (out / "model.safetensors").read_bytes() == (model / "model.safetensors").read_bytes()
    code, _, err = run(argv, capsys)  # the output is there now
    assert code == 1 and "--force" in err
    code, _, err = run([*argv, "--force"], capsys)
    assert code == 0, err


def test_choose_offset_needs_an_occupancy_head(tmp_path, capsys, random_flownet_dir):
    rec = read_bag(sample_bag_path()).slice(0, 16).save(tmp_path / "r.npz")
    argv = ["choose-offset", str(rec), "-m", str(random_flownet_dir), "-o", str(tmp_path / "o")]
    code, _, err = run(argv, capsys)
    assert code == 1 and "no occupancy head" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "o").exists()
