"""Issue 5 "done when": a short CPU training on simulated-like data (objects moving sideways by
0.5-1.5 cells a frame, ground-truth flow known) lowers the validation loss and the flow EPE
against the untrained net (zero flow = copy-last), and predicts better than copy-last."""

from __future__ import annotations

import pytest

from lidarflow.train import build_config, train
from tests.train.blobs import blob_recording


@pytest.mark.slow
def test_short_training_learns_the_motion(tmp_path):
    sources = [
        str(
            blob_recording(60, seed=s, speed_cells=v, wall=False, width=0.5).save(tmp_path / f"{s}")
        )
        for s, v in ((1, 1.0), (3, 1.5), (4, 0.5))
    ]
    flags = {
        "data.sources": sources,
        "data.grid": 32,
        "data.seq_len": 10,
        "data.warmup": 3,
        "data.stride": 3,
        "data.val_fraction": 0.2,
        "optim.batch_size": 2,
        "optim.epochs": 4,
        "optim.lr": 0.01,
        "runtime.tensorboard": False,
        "runtime.threads": 1,  # the machine is shared: 2 threads only fight the neighbours
    }
    # a fixed Gaussian size (5), so that every epoch's validation loss is the same function
    overrides = ["schedule.gaussian_start=5", "schedule.gaussian_step_epochs=1000"]
    result = train(build_config("blurred", None, flags, overrides), tmp_path / "run")
    before, after = result.rows[0], result.rows[-1]
    assert before["epoch"] == 0 and after["epoch"] == 4
    assert before["val_epe"] == before["val_epe_zero"] > 0.5  # untrained: zero flow
    assert after["val_loss"] < 0.7 * before["val_loss"]
    assert after["val_epe"] < 0.7 * before["val_epe"]
    assert after["val_f1"] > after["val_copy_last_f1"] + 0.03
    assert after["val_changed_f1"] > 0.3  # copy-last scores 0 here
