"""The supervised_flow recipe: taught by the simulator's exact flow, it learns, its run folder
loads, evaluate scores its flow on moving and static cells, and data without the truth is
refused in one line."""

from __future__ import annotations

import json

import pytest
import torch

from lidarflow.cli import main
from lidarflow.flow_supervision import window_flow_loss
from lidarflow.models import build
from lidarflow.models.weights import load_trained
from lidarflow.scan import GridSpec
from lidarflow.sim import PeopleConfig, SimConfig, simulate
from lidarflow.train import build_config, train
from lidarflow.train.data import load_train_data
from lidarflow.train.supervised import take_flow
from lidarflow.train.warm import split_batch

GRID = GridSpec(40, 40, 0.2)


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    folder = tmp_path_factory.mktemp("supervised")
    # standing still: people walk past, so the moving cells are theirs
    cfg = SimConfig(scenario="static", episode_frames=200, grid=GRID, people=PeopleConfig(count=12))
    static = simulate(60, seed=2, config=cfg).save(folder / "static.npz")
    drive = SimConfig(scenario="dynamic", episode_frames=200, grid=GRID)
    return static, simulate(40, seed=6, config=drive).save(folder / "drive.npz")


def _config(sources, **flags):
    base = {
        "data.sources": [str(s) for s in sources],
        "data.grid": GRID.height,
        "data.res": GRID.res,
        "data.seq_len": 8,
        "data.warmup": 2,
        "data.stride": 4,
        "data.val_fraction": 0.0,
        "data.epoch_windows": 0,
        "optim.epochs": 8,
        "optim.batch_size": 2,
        "optim.lr": 0.01,
        "runtime.tensorboard": False,
        "runtime.threads": 1,
        "runtime.amp": "none",
        "runtime.eval_before_training": False,
    }
    return build_config("supervised_flow", None, {**base, **flags})


def _mean_window_loss(model, cfg) -> float:
    """The supervised loss of ``model`` over every training window, in eval mode."""
    data = load_train_data(cfg.data, with_motion=True, train_flow=True)
    loader = torch.utils.data.DataLoader(data.sources[0], batch_size=8)
    model.eval()
    total = 0.0
    with torch.no_grad():
        for batch in loader:
            rest, truth = take_flow(batch)
            maps, motions, _ = split_batch(rest, True, False)
            seq = maps.float()
            out, _ = model(seq, None, *motions)
            loss = window_flow_loss(seq, out, truth, motions[0], cfg.data.warmup, 10.0, 0.15)
            total += float(loss) * len(seq)
    return total / len(data.sources[0])


@pytest.mark.slow
def test_recipe_learns_the_exact_flow_and_evaluate_scores_it(scenes, tmp_path, capsys):
    cfg = _config(scenes[:1])  # the people walking past a standing robot
    assert cfg.loss.warp == 0.0 and cfg.loss.flow_epe == 1.0 and cfg.model.head is None
    torch.manual_seed(0)
    before = _mean_window_loss(build(cfg.model.spec()), cfg)  # zero flow head: zero flow
    result = train(cfg, tmp_path / "run")
    after = _mean_window_loss(result.model, cfg)
    assert after < 0.9 * before, (before, after)

    model, card = load_trained(tmp_path / "run")
    assert card["recipe"] == "supervised_flow" and model.capabilities.flow

    out = tmp_path / "e.json"
    with pytest.raises(SystemExit) as exc:
        main([
            "evaluate", str(scenes[0]), "--model", str(tmp_path / "run"), "--grid", "40",
            "--res", "0.2", "--warmup", "4", "--threads", "1", "-o", str(out),
        ])  # fmt: skip
    assert exc.value.code == 0, capsys.readouterr().err
    scores = json.loads(out.read_text())["overall"]["run"]
    assert {"epe", "epe_moving", "epe_static"} <= set(scores)
    assert scores["epe_moving"] > scores["epe_static"]  # people are harder than walls


def test_recordings_without_ground_truth_flow_are_refused_in_one_line(scenes, tmp_path, capsys):
    from lidarflow.data import load_recording

    plain = load_recording(scenes[1])
    for key in [k for k in plain.extras if k.startswith("flow_")]:
        del plain.extras[key]
    path = plain.save(tmp_path / "plain.npz")
    with pytest.raises(SystemExit) as exc:
        main([
            "train", str(path), "--recipe", "supervised_flow", "--grid", "40", "--res", "0.2",
            "--epochs", "1", "--threads", "1", "-o", str(tmp_path / "run"),
        ])  # fmt: skip
    err = capsys.readouterr().err
    assert exc.value.code == 1 and "no ground-truth flow" in err
    assert len(err.strip().splitlines()) == 1
