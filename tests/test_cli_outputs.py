"""No command deletes or overwrites what lidarflow did not write, with or without --force
(the rule of lidarflow.atomic, kept by every command)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from tests.bagutil import write_bag
from tests.test_cli import run


def tree(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


@pytest.fixture
def bag(tmp_path):
    """A ROS 1 bag of 14 scans, in a folder of its own."""
    (tmp_path / "in").mkdir()
    return write_bag(tmp_path / "in" / "ok.bag", "ros1", {"/scan": [np.full(50, 3.0)] * 14})


def _user_folder(path: Path) -> dict[str, bytes]:
    (path / "sub").mkdir(parents=True)
    (path / "sub" / "f").write_text("x")
    (path / "config.json").write_text('{"mine": true}')
    return tree(path)


@pytest.mark.parametrize(
    ("command", "name"),
    [
        (["evaluate", "{bag}", "--baselines-only"], "res"),
        (["predict", "{bag}"], "out.mcap"),
        (["predict", "{bag}"], "out.bag"),
        (["convert", "{bag}"], "rec.npz"),
        (["show", "{bag}"], "maps.png"),
        (["simulate", "--frames", "20", "--grid", "32"], "sim.npz"),
    ],
)
def test_force_on_a_file_output_never_removes_a_folder_of_that_name(
    tmp_path, capsys, bag, command, name
):
    target = tmp_path / name
    before = _user_folder(target)
    argv = [a.format(bag=bag) for a in command]
    code, _, err = run([*argv, "-o", str(target), "--force"], capsys)
    assert code == 1 and len(err.strip().splitlines()) == 1, err
    assert "is a folder; name a file" in err, err
    assert tree(target) == before


def test_a_report_folder_lidarflow_did_not_write_is_kept(tmp_path, capsys, bag):
    target = tmp_path / "report"
    before = _user_folder(target)
    argv = ["evaluate", str(bag), "--baselines-only", "--report", str(target), "--force"]
    code, _, err = run(argv, capsys)
    assert code == 1 and "not a folder lidarflow wrote" in err, err
    assert tree(target) == before


@pytest.mark.parametrize("force", [[], ["--force"]])
def test_train_never_writes_into_a_folder_it_did_not_write(tmp_path, capsys, force):
    from tests.train.blobs import blob_recording
    from tests.train.test_cli_train import TINY

    data = blob_recording(n=30, seed=1).save(tmp_path / "data.npz")
    project = tmp_path / "project"
    before = _user_folder(project)
    (project / "run.json").write_text("{}")
    (project / "metrics.csv").write_text("a,b\n")
    before = tree(project)
    argv = ["train", str(data), "-o", str(project), "--epochs", "1", *TINY, *force]
    code, _, err = run(argv, capsys)
    assert code == 1 and len(err.strip().splitlines()) == 1, err
    assert "lidarflow did not write" in err, err
    assert tree(project) == before


def test_train_that_fails_before_its_first_epoch_leaves_no_folder(tmp_path, capsys):
    from tests.train.test_cli_train import TINY

    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a recording")
    run_dir = tmp_path / "runs" / "r"
    code, _, err = run(["train", str(bad), "-o", str(run_dir), "--epochs", "1", *TINY], capsys)
    assert code == 1, err
    assert not run_dir.exists()


@pytest.mark.slow
def test_train_force_starts_over_a_run_it_wrote(tmp_path, capsys):
    from tests.train.blobs import blob_recording
    from tests.train.test_cli_train import TINY

    data = blob_recording(n=30, seed=1).save(tmp_path / "data.npz")
    run_dir = tmp_path / "run"
    argv = ["train", str(data), "-o", str(run_dir), "--epochs", "1", *TINY]
    assert run(argv, capsys)[0] == 0
    code, _, err = run(argv, capsys)
    assert code == 1 and "already holds a training run" in err, err
    code, _, err = run([*argv, "--force"], capsys)
    assert code == 0, err
    assert (run_dir / "model.safetensors").is_file()


def test_files_of_the_model_folder_are_inputs(tmp_path, capsys, bag, random_flownet_dir):
    model = random_flownet_dir
    before = tree(model)
    for argv in (
        ["evaluate", str(bag), "--model", str(model), "-o", str(model / "model.json")],
        ["export", "--model", str(model), "-o", str(model / "model.safetensors")],
    ):
        code, _, err = run([*argv, "--force"], capsys)
        assert code == 1 and "inside the input" in err, err
    assert tree(model) == before


def test_simulate_force_leaves_only_the_new_run(tmp_path, capsys):
    out = tmp_path / "sc" / "s.npz"
    base = ["simulate", "--grid", "32", "--episode-frames", "10", "--chunk-frames", "10"]
    code, _, err = run([*base, "--frames", "40", "-o", str(out)], capsys)
    assert code == 0, err
    assert sorted(p.name for p in out.parent.glob("*.npz")) == [
        f"s-{i:03d}.npz" for i in range(4)
    ]
    code, _, err = run([*base, "--frames", "20", "-o", str(out), "--force"], capsys)
    assert code == 0, err
    assert sorted(p.name for p in out.parent.iterdir()) == ["s-000.npz", "s-001.npz", "s.json"]
    record = json.loads((out.parent / "s.json").read_text())
    assert [Path(f).name for f in record["files"]] == ["s-000.npz", "s-001.npz"]


@pytest.mark.parametrize(
    ("argv", "said"),
    [
        (["predict", "{bag}", "-o", "{tmp}/afile/out.mcap"], "afile is a file, not a folder"),
        (["convert", "{bag}", "-o", "/"], "/ holds the input"),
        (["show", "{bag}", "-o", "{tmp}/maps.xyz"], "not a picture format"),
    ],
)
def test_an_output_path_that_cannot_be_written_is_one_line(tmp_path, capsys, bag, argv, said):
    (tmp_path / "afile").write_text("mine")
    argv = [a.format(bag=bag, tmp=tmp_path) for a in argv]
    code, _, err = run(argv, capsys)
    assert code == 1 and len(err.strip().splitlines()) == 1, err
    assert said in err and "internal error" not in err, err
    assert (tmp_path / "afile").read_text() == "mine"


def _full_disk(monkeypatch, where: str) -> None:
    """Writes of files whose names hold ``where`` fail as on a full disk."""
    import errno

    original = Path.write_bytes

    def write_bytes(self, data):
        if where in self.name:
            raise OSError(errno.ENOSPC, "No space left on device", str(self))
        return original(self, data)

    monkeypatch.setattr(Path, "write_bytes", write_bytes)


@pytest.mark.slow
def test_train_on_a_full_disk_says_so_and_how_to_go_on(tmp_path, capsys, monkeypatch):
    from tests.train.blobs import blob_recording
    from tests.train.test_cli_train import TINY

    data = blob_recording(n=30, seed=1).save(tmp_path / "data.npz")
    run_dir = tmp_path / "run"
    _full_disk(monkeypatch, "state.pt")
    argv = ["train", str(data), "-o", str(run_dir), "--epochs", "1", *TINY]
    code, _, err = run(argv, capsys)
    assert code == 1 and len(err.strip().splitlines()) == 1, err
    assert "No space left on device" in err and "run the same command again" in err, err
    assert ".partial" not in err and str(run_dir) in err
    assert not run_dir.exists()  # nothing to resume: no folder left half-started


def test_a_gif_on_a_full_disk_is_one_error_naming_it(tmp_path, monkeypatch):
    from lidarflow.errors import OutputError
    from lidarflow.viz.overlay import write_gif

    _full_disk(monkeypatch, "a.gif")
    frames = [np.zeros((8, 8, 3), np.uint8)] * 2
    with pytest.raises(OutputError, match=r"a\.gif: cannot be written there \(No space left"):
        write_gif(frames, tmp_path / "a.gif")
    assert list(tmp_path.iterdir()) == []
