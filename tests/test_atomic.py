"""Files written whole or not at all (lidarflow.atomic)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from lidarflow.atomic import atomic_path, check_writable, commit, temporary, write_text
from lidarflow.errors import OutputError


def names(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


def test_a_finished_write_replaces_the_target(tmp_path):
    target = tmp_path / "r.json"
    target.write_text("old")
    write_text(target, "new")
    assert target.read_text() == "new" and names(tmp_path) == ["r.json"]


@pytest.mark.parametrize("interrupt", [RuntimeError, KeyboardInterrupt])
def test_a_write_killed_midway_leaves_the_old_target_and_no_temporary(tmp_path, interrupt):
    target = tmp_path / "x.npz"
    np.savez_compressed(target, a=np.zeros(3))
    before = target.read_bytes()
    with pytest.raises(interrupt), atomic_path(target) as tmp:
        assert tmp.parent == tmp_path and tmp.suffix == ".npz" and not tmp.exists()
        with tmp.open("wb") as f:
            f.write(b"half a file")
            raise interrupt()
    assert target.read_bytes() == before and names(tmp_path) == ["x.npz"]


def test_a_killed_first_write_leaves_nothing(tmp_path):
    with pytest.raises(KeyboardInterrupt), atomic_path(tmp_path / "new.png") as tmp:
        tmp.write_bytes(b"partial")
        raise KeyboardInterrupt
    assert names(tmp_path) == []


def test_a_folder_replaces_a_folder_whole(tmp_path):
    target = tmp_path / "bag"
    target.mkdir()
    (target / "old.db3").write_text("old")
    with atomic_path(target) as tmp:
        tmp.mkdir()
        (tmp / "new.mcap").write_text("new")
    assert names(target) == ["new.mcap"] and names(tmp_path) == ["bag"]


def test_a_writer_that_wrote_nothing_is_an_error(tmp_path):
    with pytest.raises(FileNotFoundError), atomic_path(tmp_path / "a.txt"):
        pass
    assert names(tmp_path) == []


def test_commit_of_a_file_over_a_folder(tmp_path):
    (tmp_path / "t").mkdir()
    tmp = temporary(tmp_path / "t")
    tmp.write_text("file")
    commit(tmp, tmp_path / "t")
    assert (tmp_path / "t").read_text() == "file" and names(tmp_path) == ["t"]


def test_temporaries_of_dead_processes_are_cleared_on_the_next_write(tmp_path):
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)  # fmt: skip
    stale = tmp_path / f".r.json.{int(dead.stdout)}.partial.json"
    stale.write_text("{")
    other = tmp_path / ".other.json.1.partial.json"  # a live process's (PID 1): kept
    other.write_text("{")
    write_text(tmp_path / "r.json", "{}")
    assert names(tmp_path) == [other.name, "r.json"]


def test_check_writable_refuses_an_existing_output_in_one_line(tmp_path):
    check_writable(tmp_path / "new.npz")
    (tmp_path / "old.npz").write_text("")
    with pytest.raises(OutputError, match=r"old.npz already exists; use --force to overwrite"):
        check_writable(tmp_path / "old.npz")
    check_writable(tmp_path / "old.npz", force=True)


def test_sigterm_mid_write_leaves_nothing(tmp_path):
    # A real process, told to stop by the system while it writes: the CLI's handler turns
    # SIGTERM into KeyboardInterrupt, so the temporary goes and the target never appears.
    script = textwrap.dedent(
        f"""
        import time
        from pathlib import Path
        from lidarflow.atomic import atomic_path
        from lidarflow.cli import stop_on_sigterm
        stop_on_sigterm()
        with atomic_path(Path({str(tmp_path / "out.npz")!r})) as tmp:
            tmp.write_bytes(b"partial")
            print("writing", flush=True)
            time.sleep(60)
        """
    )
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True,
                            env={**os.environ, "OMP_NUM_THREADS": "1"})  # fmt: skip
    assert proc.stdout is not None and proc.stdout.readline().strip() == "writing"
    assert len(names(tmp_path)) == 1  # the temporary, mid-write
    proc.send_signal(signal.SIGTERM)
    proc.wait(timeout=60)
    assert proc.returncode != 0 and names(tmp_path) == []


def test_an_onnx_export_that_fails_leaves_the_old_file(tmp_path, monkeypatch, capsys):
    import torch

    from tests.test_cli import run

    target = tmp_path / "m.onnx"
    target.write_bytes(b"the old export")

    def broken(model, args, f, **kwargs):
        Path(f).write_bytes(b"half a graph")
        raise RuntimeError("out of memory")

    monkeypatch.setattr(torch.onnx, "export", broken)
    code, _, err = run(["export", "-o", str(target), "--force"], capsys)
    assert code == 1 and "ONNX export failed" in err
    assert target.read_bytes() == b"the old export" and names(tmp_path) == ["m.onnx"]
