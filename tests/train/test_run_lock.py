"""A run folder that a live process trains into is that process's alone: neither ``--force``
nor ``--resume`` from another process may touch it (issue 43: two runs mixed in one folder)."""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from tests.train.test_cli_train import TINY, run_cli

ROOT = Path(__file__).resolve().parents[2]

# A trainer that stops in its last epoch (its row logged, its checkpoint not yet written) until
# the file named first on its command line appears.
PAUSED = textwrap.dedent(
    """
    import sys, time
    from pathlib import Path
    from lidarflow.train import logbook
    from lidarflow.cli import main

    go, epochs = Path(sys.argv[1]), int(sys.argv[2])
    log = logbook.Logbook.log

    def pausing(self, row):
        log(self, row)
        if row["epoch"] == epochs:
            print("in the last epoch", flush=True)
            while not go.exists():
                time.sleep(0.05)

    logbook.Logbook.log = pausing
    main(sys.argv[3:])
    """
)


@pytest.mark.slow
def test_neither_force_nor_resume_touches_a_run_being_trained(blob_files, tmp_path, capsys):
    run_dir, go = tmp_path / "run", tmp_path / "go"
    common = [str(blob_files[0]), "-o", str(run_dir), "--recipe", "paper", *TINY]
    first = subprocess.Popen(
        [sys.executable, "-c", PAUSED, str(go), "2", "train", *common, "--epochs", "2",
         "--seed", "1"],
        env={**os.environ, "PYTHONPATH": str(ROOT / "src"), "OMP_NUM_THREADS": "1"},
        stdout=subprocess.PIPE, stderr=(tmp_path / "first.err").open("w"), text=True,
    )  # fmt: skip
    try:
        assert first.stdout is not None
        lines = iter(first.stdout.readline, "")  # ends if the trainer does
        said = (tmp_path / "first.err").read_text
        assert "in the last epoch" in (s.strip() for s in lines), said()
        code, _, err = run_cli(["train", *common, "--epochs", "1", "--seed", "2", "--force"],
                               capsys)  # fmt: skip
        assert code == 1 and len(err.strip().splitlines()) == 1, err
        assert f"{run_dir} is being trained by process {first.pid}" in err, err
        code, _, err = run_cli(["train", "--resume", str(run_dir), "--epochs", "3"], capsys)
        assert code == 1 and f"being trained by process {first.pid}" in err, err
    finally:
        go.touch()
        first.wait(timeout=300)
    assert first.returncode == 0, said()
    # every file of the folder is the first run's, whole
    started = json.loads((run_dir / "run.json").read_text())
    assert "--force" not in started["command"] and "resumed" not in started
    model = json.loads((run_dir / "model.json").read_text())
    assert model["config"]["runtime"]["seed"] == 1 and model["training"]["epochs_done"] == 2
    assert json.loads((run_dir / "config.json").read_text())["runtime"]["seed"] == 1
    with (run_dir / "metrics.csv").open() as f:
        assert [int(r["epoch"]) for r in csv.DictReader(f)] == [0, 1, 2]
    assert not (run_dir / "training.lock").exists()
    # once it has ended, --force starts the folder over
    code, _, err = run_cli(["train", *common, "--epochs", "1", "--seed", "2", "--force"], capsys)
    assert code in (0, None), err
    assert json.loads((run_dir / "model.json").read_text())["config"]["runtime"]["seed"] == 2
    with (run_dir / "metrics.csv").open() as f:
        assert [int(r["epoch"]) for r in csv.DictReader(f)] == [0, 1]
    assert sorted(p.name for p in run_dir.glob("*.json")) == ["config.json", "model.json",
                                                              "run.json"]  # fmt: skip


def test_a_lock_that_cannot_be_written_leaves_nothing(tmp_path, monkeypatch):
    # a full disk while the lock is staged: no empty lock file stays behind
    import errno

    from lidarflow.train import rundir

    original = Path.write_text

    def full(self, *args, **kwargs):
        if rundir.LOCK in self.name:  # opened (created empty), then the write fails
            original(self, "")
            raise OSError(errno.ENOSPC, "No space left on device", str(self))
        return original(self, *args, **kwargs)

    monkeypatch.setattr(Path, "write_text", full)
    with pytest.raises(OSError, match="No space left"):
        rundir._lock(tmp_path)
    assert list(tmp_path.iterdir()) == []
