"""Training with ego motion: windows carry the motions, the loop feeds them, the run reloads as
an ego-motion model, and compensation pays on a simulated moving platform."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from lidarflow.models import EgoCompensated
from lidarflow.models.weights import load_trained
from lidarflow.motion.odometry import metres_to_cells, relative_motions
from lidarflow.scan import GridSpec
from lidarflow.sim import SimConfig, simulate
from lidarflow.train import build_config, train
from lidarflow.train.data import load_train_data

GRID = GridSpec(40, 40, 0.05)


@pytest.fixture(scope="module")
def driving(tmp_path_factory):
    cfg = SimConfig(scenario="dynamic", episode_frames=200, grid=GRID)
    rec = simulate(90, seed=3, config=cfg)
    return rec, rec.save(tmp_path_factory.mktemp("ego") / "drive.npz")


def _config(path, **flags):
    base = {
        "data.sources": [str(path)],
        "data.grid": GRID.height,
        "data.res": GRID.res,
        "data.seq_len": 10,
        "data.warmup": 4,
        "data.val_fraction": 0.3,
        "optim.batch_size": 4,
        "optim.epochs": 1,
        "optim.lr": 0.003,
        "runtime.tensorboard": False,
        "runtime.threads": 1,
    }
    return build_config("blurred", None, {**base, **flags})


def test_windows_carry_motions_in_cells_only_when_asked(driving):
    rec, path = driving
    cfg = _config(path)
    plain = load_train_data(cfg.data)
    assert isinstance(plain.sources[0][0], torch.Tensor)  # the default items are unchanged
    assert len(plain.val[0]) == 3
    data = load_train_data(cfg.data, with_motion=True)
    maps, motion = data.sources[0][1]
    torch.testing.assert_close(maps, plain.sources[0][1])
    _, start = data.sources[0].index[1]
    expected = metres_to_cells(relative_motions(rec.poses)[0], GRID.res)[start : start + 10]
    np.testing.assert_allclose(motion.numpy(), expected)
    assert motion.shape == (10, 3) and motion[:, 0].abs().max() > 0.1  # the robot drives
    assert len(data.val[0]) == 4 and data.val[0][3].shape == (10, 3)


def test_pose_dropout_serves_a_fixed_share_of_training_windows_without_poses(driving):
    _, path = driving
    full = load_train_data(_config(path).data, with_motion=True)
    half = load_train_data(_config(path, **{"data.pose_dropout": 0.5}).data, with_motion=True)
    dropped = []
    for i in range(len(half.sources[0])):
        motion = half.sources[0][i][1]
        if motion.abs().sum() == 0:
            dropped.append(i)
        else:
            torch.testing.assert_close(motion, full.sources[0][i][1])
        torch.testing.assert_close(half.sources[0][i][1], motion)  # the same every time
    assert 0 < len(dropped) < len(half.sources[0])
    assert all(item[3].abs().sum() > 0 for item in half.val)  # validation keeps its poses


def test_ego_training_runs_reloads_and_compensation_pays_untrained(driving, tmp_path):
    _, path = driving
    run = tmp_path / "run"
    result = train(_config(path, **{"model.kwargs": {"ego_motion": True}}), run)
    card = json.loads((run / "model.json").read_text())
    assert card["model_kwargs"] == {"ego_motion": True}
    model, _ = load_trained(run)
    assert isinstance(model, EgoCompensated)
    untrained = result.rows[0]
    # Zero world flow moved by the odometry beats copying the last map on a moving platform.
    assert untrained["val_f1"] > untrained["val_copy_last_f1"] + 0.02
    assert np.isfinite(result.rows[-1]["train_loss"])
