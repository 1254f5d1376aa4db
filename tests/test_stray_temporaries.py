"""A run killed outright (SIGKILL: no handler runs) leaves its temporary beside the target; the
next run that writes into that folder removes it, whatever it writes there (issue 43)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from lidarflow.data import read_bag, sample_bag_path
from tests.test_cli import run

ROOT = Path(__file__).resolve().parents[1]


def kill_mid_write(argv: list[str], folder: Path) -> None:
    """Run ``lidarflow ARGV``, SIGKILL it once a temporary of it is in ``folder``."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "lidarflow", *argv],
        env={**os.environ, "PYTHONPATH": str(ROOT / "src"), "OMP_NUM_THREADS": "1"},
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    deadline = time.monotonic() + 240
    while not [p for p in folder.iterdir() if ".partial" in p.name]:
        assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
        time.sleep(0.01)
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=60)
    assert [p for p in folder.iterdir() if ".partial" in p.name]  # what SIGKILL leaves


@pytest.fixture(scope="module")
def long_recording(tmp_path_factory):
    return read_bag(sample_bag_path()).save(tmp_path_factory.mktemp("in") / "long.npz")


@pytest.mark.slow
@pytest.mark.parametrize("target", ["x.bag", "x.mcap", "bagdir"])  # a file, folders staged
def test_a_killed_predict_leaves_a_temporary_the_next_run_removes(
    tmp_path, capsys, long_recording, random_flownet_dir, target
):
    out = tmp_path / "out"
    out.mkdir()
    model = ["-m", str(random_flownet_dir)]
    kill_mid_write(["predict", str(long_recording), *model, "-o", str(out / target)], out)
    code, _, err = run(["simulate", "-o", str(out / "next.npz"), "--frames", "3"], capsys)
    assert code == 0, err
    assert sorted(p.name for p in out.iterdir()) == ["next.json", "next.npz"]


def test_a_killed_simulate_leaves_a_temporary_the_next_run_removes(tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    argv = ["simulate", "-o", str(out / "sim.npz"), "--frames", "900", "--chunk-frames", "300"]
    kill_mid_write(argv, out)
    code, _, err = run(["simulate", "-o", str(out / "next.npz"), "--frames", "3"], capsys)
    assert code == 0, err
    left = sorted(p.name for p in out.iterdir())
    assert "next.npz" in left and not [n for n in left if ".partial" in n], left


def test_a_temporary_of_a_live_process_or_of_this_one_is_kept(tmp_path):
    from lidarflow.atomic import clear_stale, temporary

    live = subprocess.Popen(["sleep", "60"])
    try:
        theirs = tmp_path / f".a.bag.{live.pid}.partial.bag"
        theirs.write_bytes(b"being written")
        mine = temporary(tmp_path / "b.mcap")
        mine.mkdir()
        # this process's PID, not made by it: a killed run's in a container whose PIDs repeat
        before = tmp_path / f".c.npz.{os.getpid()}.partial.npz"
        before.write_bytes(b"left")
        user = tmp_path / ".notes.7.partial.txt"  # not a name lidarflow makes: .txt is not
        # the suffix of "notes"
        user.write_text("the user's")
        (tmp_path / f".d.{live.pid}.partial.wrong").write_text("not ours either")
        assert clear_stale(tmp_path) == [before]
        assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
            [theirs.name, mine.name, user.name, f".d.{live.pid}.partial.wrong"]
        )
    finally:
        live.kill()
        live.wait()
    assert clear_stale(tmp_path) == [theirs]  # its process is gone now
