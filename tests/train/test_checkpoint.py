"""Checkpoint files: atomic writes, RNG capture, refusal to save non-finite weights."""

from __future__ import annotations

import os
import random
import stat

import numpy as np
import pytest
import torch

from lidarflow.errors import TrainError
from lidarflow.train import checkpoint
from lidarflow.train.checkpoint import (
    atomic_write,
    capture_rng,
    load_weights,
    remove_temporaries,
    restore_rng,
    save_weights,
)


def test_atomic_write_leaves_the_old_file_when_the_writer_fails(tmp_path):
    target = tmp_path / "f.json"
    target.write_text("old")

    def broken(tmp):
        tmp.write_text("half")
        raise OSError("disk full")

    with pytest.raises(OSError):
        atomic_write(target, broken)
    assert target.read_text() == "old" and list(tmp_path.iterdir()) == [target]
    (tmp_path / ".f.json.abc.tmp").write_text("left by a kill")
    assert remove_temporaries(tmp_path) == 1 and list(tmp_path.iterdir()) == [target]


def test_written_files_follow_the_umask(tmp_path):
    # mkstemp's 0600 left every file of a run unreadable to other users
    old = os.umask(0o022)
    try:
        checkpoint.write_json(tmp_path / "model.json", {})
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp_path / "model.json").stat().st_mode) == 0o644


def test_rng_state_round_trips():
    random.seed(1), np.random.seed(2), torch.manual_seed(3)
    state = capture_rng()
    first = (random.random(), np.random.rand(), torch.rand(1).item())
    restore_rng(state)
    assert (random.random(), np.random.rand(), torch.rand(1).item()) == first


def test_weights_round_trip_and_non_finite_weights_are_refused(tmp_path):
    net = torch.nn.Linear(3, 2)
    save_weights(net, tmp_path / "w.safetensors", {"epoch": 3})
    other = torch.nn.Linear(3, 2)
    load_weights(other, tmp_path / "w.safetensors")
    assert torch.equal(other.weight, net.weight)
    with pytest.raises(TrainError, match="do not fit"):
        load_weights(torch.nn.Linear(4, 2), tmp_path / "w.safetensors")
    with torch.no_grad():
        net.weight[0, 0] = float("nan")
    with pytest.raises(TrainError, match="non-finite weights"):
        save_weights(net, tmp_path / "bad.safetensors")
    assert not (tmp_path / "bad.safetensors").exists()


@pytest.mark.parametrize("name", ["epoch_0001.safetensors", "epoch_0001.state.pt"])
@pytest.mark.parametrize("keep", [0.0, 0.5])
def test_a_damaged_checkpoint_is_named_as_such(name, keep, tmp_path):
    # a state file cut short said "[Errno 22] Invalid argument"; an empty one raised EOFError,
    # which the CLI's library took for Ctrl-D ("Aborted.")
    net = torch.nn.Linear(3, 2)
    optimizer = torch.optim.Adam(net.parameters())
    scheduler = torch.optim.lr_scheduler.StepLR(optimizer, 5)
    checkpoint.save_checkpoint(tmp_path, 1, net, optimizer, scheduler, {})
    damaged = tmp_path / "checkpoints" / name
    damaged.write_bytes(damaged.read_bytes()[: int(damaged.stat().st_size * keep)])
    with pytest.raises(TrainError) as caught:
        checkpoint.load_checkpoint(tmp_path, net, optimizer, scheduler)
    text = str(caught.value)
    assert text.startswith(f"{damaged}: damaged checkpoint"), text
    assert "Errno" not in text and "header" not in text, text
