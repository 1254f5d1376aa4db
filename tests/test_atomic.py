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

from lidarflow import atomic
from lidarflow.atomic import (
    STAMP,
    atomic_path,
    atomic_paths,
    check_not_input,
    check_writable,
    write_text,
)
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


def _written_folder(target: Path, name: str) -> None:
    with atomic_path(target) as tmp:
        tmp.mkdir()
        (tmp / name).write_text(name)


def test_a_folder_replaces_a_folder_lidarflow_wrote_whole(tmp_path):
    target = tmp_path / "bag"
    _written_folder(target, "old.db3")
    assert names(target) == [STAMP, "old.db3"]
    _written_folder(target, "new.mcap")
    assert names(target) == [STAMP, "new.mcap"] and names(tmp_path) == ["bag"]


def test_a_folder_is_replaced_in_one_step(tmp_path, monkeypatch):
    # no moment without a folder at the target: the old one is never moved aside first
    target = tmp_path / "report"
    _written_folder(target, "old.html")

    def no_two_step_move(*args):
        raise AssertionError("moved aside")

    monkeypatch.setattr(atomic.os, "replace", no_two_step_move)
    _written_folder(target, "new.html")
    assert names(target) == [STAMP, "new.html"] and names(tmp_path) == ["report"]


def test_a_folder_lidarflow_did_not_write_is_never_replaced(tmp_path):
    target = tmp_path / "project"
    (target / "src").mkdir(parents=True)
    (target / "src" / "main.py").write_text("print()")
    with pytest.raises(OutputError, match="not a folder lidarflow wrote"):
        check_writable(target, force=True, folder=True)
    with pytest.raises(OutputError, match="not a folder lidarflow wrote"):
        _written_folder(target, "index.html")
    assert (target / "src" / "main.py").read_text() == "print()"
    assert names(tmp_path) == ["project"]


def test_a_file_never_replaces_a_folder(tmp_path):
    (tmp_path / "res" / "sub").mkdir(parents=True)
    (tmp_path / "res" / "sub" / "f").write_text("x")
    with pytest.raises(OutputError, match="is a folder; name a file"):
        check_writable(tmp_path / "res", force=True)
    with pytest.raises(OutputError, match="is a folder; name a file"):
        write_text(tmp_path / "res", "{}")
    assert (tmp_path / "res" / "sub" / "f").read_text() == "x"
    assert names(tmp_path) == ["res"]


def test_an_output_that_appeared_while_writing_is_not_replaced(tmp_path):
    # two runs, one new output: the one that finishes second is refused
    target = tmp_path / "out.json"
    check_writable(target)
    refused = pytest.raises(OutputError, match="appeared while this run wrote it")
    with refused, atomic_path(target) as tmp:
        tmp.write_text("mine")
        target.write_text("the other run's")
    assert target.read_text() == "the other run's" and names(tmp_path) == ["out.json"]


def test_a_named_output_with_force_is_replaced(tmp_path):
    target = tmp_path / "out.json"
    target.write_text("old")
    check_writable(target, force=True)
    write_text(target, "new")
    assert target.read_text() == "new"


def test_a_set_of_outputs_appears_whole_or_not_at_all(tmp_path):
    targets = [tmp_path / f"s-{i:03d}.npz" for i in range(3)]
    with pytest.raises(KeyboardInterrupt), atomic_paths(targets) as temps:
        temps[0].write_text("0")
        raise KeyboardInterrupt
    assert names(tmp_path) == []
    with atomic_paths(targets) as temps:
        for i, tmp in enumerate(temps):
            tmp.write_text(str(i))
    assert [t.read_text() for t in targets] == ["0", "1", "2"]


def test_without_renameat2_the_same_rule_holds(tmp_path, monkeypatch):
    monkeypatch.setattr(atomic, "_renameat2", None)
    target = tmp_path / "out.json"
    check_writable(target)
    write_text(target, "first")
    with pytest.raises(OutputError, match="appeared while this run wrote it"):
        write_text(target, "second")
    assert target.read_text() == "first"
    _written_folder(tmp_path / "r", "a")
    _written_folder(tmp_path / "r", "b")
    assert names(tmp_path / "r") == [STAMP, "b"] and names(tmp_path) == ["out.json", "r"]


def test_files_inside_an_input_folder_are_inputs(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    (run / "model.json").write_text("{}")
    with pytest.raises(OutputError, match="inside the input"):
        check_not_input(run / "model.json", [run])
    check_not_input(run / "results.json", [run])  # a new file beside a model's breaks nothing
    bag = tmp_path / "bag"
    bag.mkdir()
    (bag / "metadata.yaml").write_text("")
    with pytest.raises(OutputError, match="inside the input"):
        check_not_input(bag / "new.mcap", [bag])


def test_a_writer_that_wrote_nothing_is_an_error(tmp_path):
    with pytest.raises(FileNotFoundError), atomic_path(tmp_path / "a.txt"):
        pass
    assert names(tmp_path) == []


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
