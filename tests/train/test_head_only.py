"""The head_only recipe: the occupancy head without the flow network (issue 36)."""

from __future__ import annotations

import json

import pytest
import torch

from lidarflow.errors import TrainError
from lidarflow.models import build
from lidarflow.models.presets import resolve_model
from lidarflow.scan import GridSpec
from lidarflow.sim import SimConfig, simulate
from lidarflow.train import build_config, recipe, train
from lidarflow.train.config_io import config_from_dict, config_to_dict
from lidarflow.train.model_setup import load_init, make_optimizer
from tests.conftest import FLOW_MODEL
from tests.head_only_pair import head_only, save_model_dir

GRID = GridSpec(40, 40, 0.05)


def test_the_recipe_is_the_head_recipe_without_the_flow_and_its_lr_tricks():
    head, only = recipe("head"), recipe("head_only")
    assert only.recipe == "head_only" and only.model.flow is None
    assert only.model.head == head.model.head and only.model.init == "bundled"
    assert only.model.ego_motion and only.model.poses_optional and only.decision.online
    assert only.data == head.data
    # The head's rate of the head recipe, now the only group's.
    assert only.optim.lr * only.optim.head_lr_scale == head.optim.lr * head.optim.head_lr_scale
    assert only.optim.lr == 0.03 and only.optim.head_lr_scale == 1.0
    assert only.loss.warp == 0.0 and only.loss.occupancy_bce == 1.0 and not only.schedule.gaussian
    again = config_from_dict(json.loads(json.dumps(config_to_dict(only))))
    assert again == only


def test_set_model_flow_null_takes_the_flow_network_away():
    config = build_config("head", None, None, ["model.flow=null"])
    assert config.model.flow is None and config.model.spec().flow is None
    back = build_config("head_only", None, None, ["model.flow.hidden_channels=8"])
    assert back.model.flow is not None and back.model.flow.hidden_channels == 8


def test_it_starts_from_the_bundled_head_and_trains_it_alone_at_0_03():
    config = recipe("head_only")
    model = build(config.model.spec())
    assert not load_init(model, "bundled")  # the head came across: not left new
    bundled = resolve_model("bundled")[0].state_dict()
    own = model.state_dict()
    assert own and all(".flow." not in name for name in own)
    for name, value in own.items():
        torch.testing.assert_close(value, bundled[name])
    groups = make_optimizer(config, model).param_groups
    assert len(groups) == 1 and groups[0]["lr"] == 0.03
    assert sum(p.numel() for p in groups[0]["params"]) == sum(v.numel() for v in own.values())


@pytest.mark.slow
def test_a_tiny_run_learns_and_leaves_a_flow_free_model(tmp_path):
    cfg = SimConfig(scenario="dynamic", episode_frames=200, grid=GRID)
    drive = simulate(80, seed=4, config=cfg)
    path = drive.save(tmp_path / "drive.npz")
    flags = {
        "data.sources": [str(path)],
        "data.grid": GRID.height,
        "data.res": GRID.res,
        "data.seq_len": 8,
        "data.warmup": 3,
        "data.stride": 4,
        "data.val_fraction": 0.25,
        "data.epoch_windows": 12,
        "optim.batch_size": 2,
        "optim.epochs": 3,
        "runtime.tensorboard": False,
        "runtime.threads": 1,
        "model.init": str(FLOW_MODEL),  # v8's head (v9, the bundled one, is it trained on)
    }
    result = train(build_config("head_only", None, flags), tmp_path / "run")
    losses = [row["train_loss"] for row in result.rows if "train_loss" in row]
    assert losses[-1] < 0.9 * losses[0], losses
    trained, card = resolve_model(tmp_path / "run")
    assert card["model_kwargs"]["flow_network"] is False
    assert not trained.capabilities.flow and trained.capabilities.occupancy_head


def test_a_head_of_other_inputs_starts_afresh_and_a_flow_model_refuses_a_flow_free_init(tmp_path):
    config = build_config("head_only", None, None, ["model.head.memory_decays=0.5"])
    model = build(config.model.spec())
    fresh = {k: v.clone() for k, v in model.state_dict().items()}
    assert load_init(model, "bundled")  # no weight fits: the head is left new
    for name, value in model.state_dict().items():
        torch.testing.assert_close(value, fresh[name])
    run = save_model_dir(head_only(ego=True), tmp_path / "noflow")
    flow_model = build(recipe("head").model.spec())
    with pytest.raises(TrainError, match=r"model.init .*has no flow network.*--init RUN"):
        load_init(flow_model, str(run))
    with pytest.raises(TrainError, match=r"model.init bundled: it has no flow network"):
        load_init(flow_model, "bundled")  # the head alone since v9
