"""Tiny data for the studies' smoke tests: simulated recordings of a few dozen frames, and the
config keys that make a training run a couple of small steps."""

from __future__ import annotations

from pathlib import Path

import pytest

from lidarflow.sim import SimConfig, write_simulation

#: a training run of one epoch of two short windows on a small grid
_TINY_TRAINING = (
    "data.grid=32", "data.seq_len=6", "data.warmup=2", "data.epoch_windows=2",
    "data.val_fraction=0.25", "optim.epochs=1", "optim.batch_size=2",
    "runtime.threads=1", "runtime.tensorboard=false",
)  # fmt: skip


@pytest.fixture
def tiny_training() -> list[str]:
    """Config keys (``KEY=VALUE``) that make a training run one epoch of two short windows."""
    return list(_TINY_TRAINING)


@pytest.fixture(scope="session")
def sim_recordings(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    """Two simulated recordings of 24 frames: one static, one driving (with poses)."""
    folder = tmp_path_factory.mktemp("sim")
    paths = []
    for seed, scenario in ((7, "static"), (8, "dynamic")):
        path = folder / f"{scenario}.npz"
        write_simulation(path, 24, seed, SimConfig(scenario=scenario))
        paths.append(path)
    return paths


@pytest.fixture(scope="session")
def eval_reports(sim_recordings: list[Path], tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder of evaluation reports as `lidarflow evaluate --online-decision --json` writes
    them, ``eval_<recording>.json``: the bundled model (named ``run``) on each simulated one."""
    from lidarflow.data import load_any
    from studies.harness import stem, write_json
    from studies.scoring import evaluate

    folder = tmp_path_factory.mktemp("reports")
    for path in sim_recordings:
        report = evaluate([(str(path), load_any(path))], {"run": "bundled"}, online=True)
        write_json(folder / f"eval_{stem(path)}.json", report)
    return folder
