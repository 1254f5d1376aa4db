"""Training config: paper defaults, recipes, file/flag/--set layering, JSON round trip."""

from __future__ import annotations

import json

import pytest

from lidarflow.errors import TrainError
from lidarflow.losses import LossConfig
from lidarflow.models import HeadConfig, ModelSpec
from lidarflow.models.presets import bundled_model_dir
from lidarflow.train.config import TrainConfig
from lidarflow.train.config_io import (
    apply_overrides,
    build_config,
    config_from_dict,
    config_to_dict,
)
from lidarflow.train.recipes import RECIPES, recipe


def test_defaults_are_the_papers_recipe():
    c = TrainConfig()
    assert (c.data.seq_len, c.data.warmup) == (20, 10)
    assert (c.optim.batch_size, c.optim.lr, c.optim.epochs) == (32, 0.01, 200)
    assert (c.schedule.lr_step_epochs, c.schedule.lr_gamma) == (25, 0.5)
    s = c.schedule
    assert (s.gaussian, s.gaussian_start, s.gaussian_step_epochs, s.gaussian_min) == (
        True,
        9,
        25,
        1,
    )
    assert c.loss == LossConfig.paper()
    assert (c.data.grid, c.data.res) == (100, 0.1)


def test_recipes_differ_only_where_they_should():
    assert set(RECIPES) >= {"paper", "blurred"}
    paper, blurred = recipe("paper"), recipe("blurred")
    assert blurred.loss == LossConfig.blurred_both() != paper.loss
    assert (blurred.optim, blurred.data, blurred.schedule) == (
        paper.optim,
        paper.data,
        paper.schedule,
    )
    with pytest.raises(TrainError, match="unknown recipe 'nope'"):
        recipe("nope")


def test_head_recipe_is_the_one_validated_leave_one_out():
    # docs/research/leave_one_out/README.md: the residual recipe (since removed: the blurred
    # one, a cross-entropy on the next map and its schedule, written out below), that study's
    # config file and these flags. The recipe must not drift from what was measured.
    from pathlib import Path

    configs = Path(__file__).parents[2] / "docs/research/leave_one_out/configs"
    study = configs / "head_subcell_online.json"
    flags = {"optim.epochs": 3, "optim.batch_size": 4, "data.seq_len": 16, "data.warmup": 6}
    # The folds ran with --amp bf16 on CPUs that compute it natively, which is what the
    # recipe's "auto" picks there (and fp32 where bf16 would be emulated).
    flags |= {"optim.lr": 1e-6, "runtime.amp": "auto", "runtime.channels_last": True}
    residual = {"loss.occupancy_bce": 1.0, "schedule.lr_step_epochs": 3}
    residual |= {"schedule.gaussian_step_epochs": 2}
    # decision.movers came later (issue 44, docs/research/carry_movers/): the decision, not the
    # training, and validated in its own leave-one-out study
    residual |= {"decision.movers": True}
    measured = build_config("blurred", study, flags | residual)
    head = recipe("head")
    assert head.model.init == "bundled" and measured.model.init is None
    for section in ("data", "optim", "schedule", "loss", "runtime", "decision"):
        assert getattr(head, section) == getattr(measured, section), section
    # the same model: the study's file gave it flat (model.kwargs), as configs did then
    assert head.model.spec() == measured.model.spec()
    # That study's file kept the decision among the model's kwargs, as configs did then: it is
    # read into the decision section, where the recipe has it.
    assert head.decision.online


def test_default_recipe_is_head_only_for_lidar_flownet_only():
    from lidarflow.train.recipes import default_recipe

    assert default_recipe() == default_recipe("flownet") == "head_only"  # v9: no flow network
    assert default_recipe("deeptracking") == "paper"
    assert default_recipe("flownet", ego_motion=True) == "paper"
    assert TrainConfig().recipe == "paper"  # the dataclasses keep the paper's values


def test_json_round_trip_of_every_recipe():
    for name in RECIPES:
        c = apply_overrides(recipe(name), ["optim.lr=0.003", "data.sources=a.npz,b.npz"])
        again = config_from_dict(json.loads(json.dumps(config_to_dict(c))))
        assert again == c


def test_overrides_are_typed():
    c = apply_overrides(
        TrainConfig(),
        [
            "optim.lr=3e-3",
            "optim.epochs=5",
            "schedule.gaussian=false",
            "data.mix=0.7,0.3",
            "data.topic=/scan",
            "optim.grad_clip=1",  # an int where a float is expected is fine
            "model.head.hidden_channels=8",
            "model.head.memory_decays=0.5,0.9",
        ],
    )
    assert c.optim.lr == 0.003 and isinstance(c.optim.lr, float)
    assert c.optim.epochs == 5 and c.schedule.gaussian is False
    assert c.data.mix == [0.7, 0.3] and c.data.topic == "/scan"
    assert c.optim.grad_clip == 1.0 and isinstance(c.optim.grad_clip, float)
    assert c.model.head == HeadConfig(memory_decays=(0.5, 0.9), hidden_channels=8)
    assert apply_overrides(c, ["data.topic=null"]).data.topic is None


@pytest.mark.parametrize(
    ("item", "message"),
    [
        ("optim.lr", "section.field=value"),
        ("optim.nope=1", "unknown setting 'optim.nope'"),
        ("optim.epochs=2.5", "optim.epochs: expected int"),
        ("schedule.gaussian=maybe", "expected bool"),
        ("optim=3", "expected a table"),
        ("loss.smoothness=-1", "smoothness must be >= 0"),
    ],
)
def test_bad_overrides_name_the_setting(item, message):
    with pytest.raises(TrainError, match=message):
        apply_overrides(TrainConfig(), [item])


def test_layering_recipe_file_flags_set(tmp_path):
    toml = tmp_path / "c.toml"
    toml.write_text('recipe = "blurred"\n[optim]\nlr = 0.002\nepochs = 7\n[data]\nseq_len = 12\n')
    c = build_config(None, toml, {"optim.epochs": 9, "optim.batch_size": None}, ["data.seq_len=14"])
    assert c.recipe == "blurred" and c.loss == LossConfig.blurred_both()
    assert (c.optim.lr, c.optim.epochs, c.optim.batch_size, c.data.seq_len) == (0.002, 9, 32, 14)
    # a recipe named on the command line beats the file's, and the file still applies
    c2 = build_config("paper", toml)
    assert c2.loss == LossConfig.paper() and c2.optim.lr == 0.002
    # a saved config.json loads back to the same config
    js = tmp_path / "config.json"
    js.write_text(json.dumps(config_to_dict(c)))
    assert build_config(None, js) == c


def test_bad_config_files_and_values(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(TrainError, match="not valid JSON"):
        build_config(None, bad)
    # any name but .toml reads as JSON, and says so (it said "not valid txt")
    (tmp_path / "bad.txt").write_text("{not json")
    with pytest.raises(TrainError, match=r"bad\.txt: not valid JSON"):
        build_config(None, tmp_path / "bad.txt")
    # a binary file given by mistake raised UnicodeDecodeError, an internal error
    (tmp_path / "rec.npz").write_bytes(b"PK\x03\x04\xc0\xff")
    with pytest.raises(TrainError, match=r"rec\.npz: not a config file"):
        build_config(None, tmp_path / "rec.npz")
    with pytest.raises(TrainError, match="cannot read"):
        build_config(None, tmp_path / "missing.json")
    with pytest.raises(TrainError, match=r"data\.warmup"):
        build_config(None, None, {"data.seq_len": 5, "data.warmup": 4})
    with pytest.raises(TrainError, match="Gaussian sizes must be odd"):
        build_config(None, None, {"schedule.gaussian_start": 8})
    with pytest.raises(TrainError, match=r"model\.name"):
        build_config(None, None, {"model.name": "resnet"})
    for value in (-0.1, 1.5):
        with pytest.raises(TrainError, match=r"data\.pose_dropout is a fraction"):
            build_config(None, None, {"data.pose_dropout": value})
    assert build_config(None, None, {"data.pose_dropout": 1.0}).data.pose_dropout == 1
    # data.slower_copies, measured without gain, is gone: a config written while it existed
    # (off: []) still reads, one that turns it on is refused.
    assert build_config(None, None, {"data.slower_copies": []}) == build_config()
    bundled = json.loads((bundled_model_dir() / "model.json").read_text())["config"]
    assert bundled["data"]["slower_copies"] == [] and config_from_dict(bundled).data.sources
    with pytest.raises(TrainError, match=r"data\.slower_copies was measured without gain"):
        build_config(None, None, {"data.slower_copies": [2]})
    # Options measured without gain are gone: a config naming one is refused.
    for removed in ("data.static_shift", "data.sensor_copies", "data.scan_motions"):
        with pytest.raises(TrainError):
            build_config(None, None, {removed: 1})


def test_a_gap_threshold_of_one_period_or_less_is_refused_before_any_data_loads():
    # every step would be a gap; it reached the gap rule as an internal error after loading
    with pytest.raises(TrainError, match=r"data\.max_gap_periods must be > 1"):
        build_config(None, None, {}, ["data.max_gap_periods=1.0"])


def test_the_decision_is_its_own_section_and_old_configs_move_it_there():
    from lidarflow.train.config import DecisionConfig

    assert recipe("head").decision == DecisionConfig(0.0, True, movers=True)
    assert recipe("paper").decision == DecisionConfig()
    config = build_config(None, None, {}, ["decision.offset=0.9", "decision.online=true"])
    assert config.decision == DecisionConfig(0.9, True)
    # Before issue 35 it travelled among the model's kwargs: read from there, it moves.
    old = {"occupancy_head": True, "online_decision": True, "decision_offset": 0.5}
    config = build_config(None, None, {"model.kwargs": old})
    assert config.decision == DecisionConfig(0.5, True)
    assert config.model.spec() == ModelSpec(head=HeadConfig())


def test_the_model_is_typed_and_its_flat_form_still_read():
    config = build_config(
        None, None, {}, ["model.head.subcell_input=true", "model.ego_motion=true"]
    )
    assert config.model.spec() == ModelSpec(head=HeadConfig(subcell_input=True), ego_motion=True)
    # a file from before issue 35: the whole model as one flat table, read as the same model
    flat = {"occupancy_head": True, "subcell_input": True, "ego_motion": True}
    assert build_config(None, None, {"model.kwargs": flat}).model.spec() == config.model.spec()
    # a run's config.json from before resumes as the same config
    head = recipe("head")
    saved = config_to_dict(head)
    saved["model"] = {"name": "flownet", "init": "bundled", "kwargs": head.model.spec().to_kwargs()}
    saved["model"]["kwargs"]["online_decision"] = True
    del saved["decision"]
    assert config_from_dict(saved) == head
    with pytest.raises(TrainError, match=r"model\.kwargs: unexpected model arguments: nonsense"):
        build_config(None, None, {"model.kwargs": {"nonsense": 1}})
    with pytest.raises(TrainError, match=r"model\.kwargs: warp_input was measured without gain"):
        build_config(None, None, {"model.kwargs": {"occupancy_head": True, "warp_input": True}})
    with pytest.raises(TrainError, match="shift_memories needs constant_velocity_input"):
        build_config(None, None, {}, ["model.head.shift_memories=true"])
    with pytest.raises(TrainError, match="poses_optional needs ego_motion"):
        build_config(None, None, {"model.poses_optional": True})
