"""Windows that start from the occupancy head's memories as streaming leaves them."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lidarflow.models import build_model
from lidarflow.scan import GridSpec
from lidarflow.sim import SimConfig, simulate
from lidarflow.train import build_config, train
from lidarflow.train.data import load_train_data
from lidarflow.train.warm import split_batch, start_state, stream_start_states

GRID = GridSpec(40, 40, 0.05)
HEAD = {
    "occupancy_head": True,
    "memory_decays": [0.5, 0.95],
    "constant_velocity_input": True,
    "shift_memories": True,
}


@pytest.fixture(scope="module")
def driving(tmp_path_factory):
    cfg = SimConfig(scenario="dynamic", episode_frames=200, grid=GRID)
    rec = simulate(60, seed=4, config=cfg)
    return rec.save(tmp_path_factory.mktemp("warm") / "drive.npz")


def _config(path, recipe="blurred", **flags):
    base = {
        "loss.occupancy_bce": 1.0,  # a head fitted by cross-entropy
        "data.sources": [str(path)],
        "data.grid": GRID.height,
        "data.res": GRID.res,
        "data.seq_len": 8,
        "data.warmup": 3,
        "data.stride": 8,
        "data.val_fraction": 0.25,
        "optim.batch_size": 2,
        "optim.epochs": 1,
        "runtime.tensorboard": False,
        "runtime.threads": 1,
    }
    return build_config(recipe, None, {**base, **flags})


def _head_state_after(model, maps: np.ndarray, motions: np.ndarray | None) -> torch.Tensor:
    seq = torch.from_numpy(maps.astype(np.float32))[None]
    if motions is None:
        _, state = model(seq)
    else:
        _, state = model(seq, None, torch.from_numpy(motions)[None])
    return state[-1][0]


@pytest.mark.parametrize(("ego", "dropout"), [(False, 0.5), (True, 0.5), (True, 0.0)])
def test_each_window_starts_from_the_memories_streamed_to_its_first_frame(driving, ego, dropout):
    kwargs = {**HEAD, "ego_motion": True, "poses_optional": True} if ego else HEAD
    config = _config(driving, **{"data.pose_dropout": dropout})
    data = load_train_data(config.data, with_motion=ego)
    windows = data.sources[0]
    model = build_model("flownet", **kwargs)
    stream_start_states(model, windows)
    maps = windows.maps[0]
    served = set()
    for i, (_, start) in enumerate(windows.index):
        item = windows[i]
        posed = ego and not windows.dropped(i)
        motions = windows.motions[0][:start] if posed else None
        expected = _head_state_after(model, maps[:start], motions) if start else None
        got = item[-1]
        assert got.shape == (model.state_channels()[-1], *GRID.shape)
        if expected is None:
            assert not got.any()
        else:
            torch.testing.assert_close(got.float(), expected, atol=2e-3, rtol=0)
            assert got.abs().max() > 0.1  # the slow memory has built up
        served.add(posed)
    # With pose dropout an ego-motion model's windows start from both trajectories, which differ;
    # without it only the posed one is streamed.
    assert served == ({True, False} if ego and dropout else {True} if ego else {False})
    if ego and not dropout:
        assert not any(not posed for _, _, posed in windows.start_states)
    elif ego:
        posed = [k for k in windows.start_states if k[2] and k[1] > 0]
        assert any(
            not np.array_equal(windows.start_states[k], windows.start_states[(k[0], k[1], False)])
            for k in posed
        )


def test_training_from_streamed_memories_runs_and_starts_from_them(driving, tmp_path):
    result = train(
        _config(driving, **{"model.kwargs": HEAD, "data.memories_from_stream": True}),
        tmp_path / "run",
    )
    assert np.isfinite(result.rows[-1]["train_loss"])
    data = load_train_data(_config(driving).data)
    model = build_model("flownet", **HEAD)
    stream_start_states(model, data.sources[0])
    i = next(i for i, (_, s) in enumerate(data.sources[0].index) if s > 0)
    maps, motions, first = split_batch(
        torch.utils.data.default_collate([data.sources[0][i]]), ego=False, warm=True
    )
    assert motions == []
    state = start_state(model, maps.float(), first)
    assert all(not s.any() for s in state[:-1]) and state[-1].any()  # GRUs zero, memories not
    assert start_state(model, maps.float(), None) is None


def test_memories_from_stream_needs_an_occupancy_head(driving, tmp_path):
    from lidarflow.errors import TrainError

    with pytest.raises(TrainError, match="memories_from_stream"):
        train(_config(driving, "blurred", **{"data.memories_from_stream": True}), tmp_path / "run")
