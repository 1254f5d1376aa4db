"""What a command refuses before any work (issue 43): a horizon the recording cannot use, an
output that is one of its inputs."""

from __future__ import annotations

import numpy as np
import pytest

from tests.bagutil import write_bag
from tests.test_cli import run


@pytest.fixture
def short_bag(tmp_path):
    """A ROS 1 bag of 14 scans."""
    return write_bag(tmp_path / "short.bag", "ros1", {"/scan": [np.full(50, 3.0)] * 14})


@pytest.mark.parametrize("command", ["predict", "live"])
def test_a_horizon_the_recording_cannot_use_is_refused_at_once(tmp_path, capsys, short_bag,
                                                               command):  # fmt: skip
    # 14 frames hold predictions up to 13 ahead; 100000 ahead ran with no bound (issue 43)
    out = ["-o", str(tmp_path / "x.mcap")] if command == "predict" else ["--port", "0"]
    for horizon in ("14", "100000"):
        code, _, err = run([command, str(short_bag), *out, "--horizon", horizon], capsys)
        assert code == 1 and len(err.strip().splitlines()) == 1, err
        assert f"{short_bag}: too short for --horizon {horizon}: needs at least" in err
        assert "has 14 frames" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["short.bag"]


def _refused(code: int, err: str, what: str) -> None:
    assert code == 1 and len(err.strip().splitlines()) == 1, err
    assert what in err and ("name another output" in err or "name an output outside" in err), err


@pytest.mark.parametrize("force", [[], ["--force"]])
def test_an_output_that_is_an_input_is_refused_even_with_force(tmp_path, capsys, short_bag,
                                                               force):  # fmt: skip
    before = short_bag.read_bytes()
    link = tmp_path / "link.bag"
    link.symlink_to(short_bag)
    hard = tmp_path / "hard.bag"
    hard.hardlink_to(short_bag)
    for out in (short_bag, link, hard):  # the same path, through a symbolic link, an inode
        code, _, err = run(["predict", str(short_bag), "-o", str(out), *force], capsys)
        _refused(code, err, f"{out} is the input {short_bag}")
        code, _, err = run(
            ["evaluate", str(short_bag), "--baselines-only", "-o", str(out), *force], capsys
        )
        _refused(code, err, f"{out} is the input {short_bag}")
    rec = tmp_path / "rec.npz"
    assert run(["convert", str(short_bag), "-o", str(rec)], capsys)[0] == 0
    rec_before = rec.read_bytes()
    code, _, err = run(["convert", str(rec), "-o", str(rec), *force], capsys)
    _refused(code, err, f"{rec} is the input {rec}")
    code, _, err = run(["show", str(rec), "-o", str(rec), *force], capsys)
    _refused(code, err, f"{rec} is the input {rec}")
    assert short_bag.read_bytes() == before and rec.read_bytes() == rec_before


def test_an_output_folder_holding_an_input_or_inside_an_input_bag_is_refused(tmp_path, capsys):
    report = tmp_path / "report"
    report.mkdir()
    (report / "index.html").write_text("an old report")  # a folder --force would replace
    bag = write_bag(report / "in.bag", "ros1", {"/scan": [np.full(50, 3.0)] * 14})
    argv = ["evaluate", str(bag), "--baselines-only", "--report", str(report), "--force"]
    code, _, err = run(argv, capsys)
    _refused(code, err, f"{report} holds the input {bag}")
    assert bag.is_file()
    ros2 = write_bag(tmp_path / "ros2bag", "mcap", {"/scan": [np.full(50, 3.0)] * 14})
    storage = next(p for p in ros2.iterdir() if p.suffix == ".mcap")
    for out in (ros2, storage, ros2 / "new.mcap"):  # the bag, its file, beside its file
        code, _, err = run(["predict", str(ros2), "-o", str(out), "--force"], capsys)
        assert code == 1 and str(ros2) in err and "name a" in err, err
    assert sorted(p.name for p in ros2.iterdir()) == sorted(["metadata.yaml", storage.name])


def test_export_refuses_to_write_over_the_model_it_exports(tmp_path, capsys, random_flownet_dir):
    weights = random_flownet_dir / "model.safetensors"
    before = weights.read_bytes()
    code, _, err = run(["export", "-m", str(weights), "-o", str(weights), "--force"], capsys)
    _refused(code, err, f"{weights} is the input {weights}")
    assert weights.read_bytes() == before


def test_train_force_refuses_a_run_folder_that_holds_its_data(tmp_path, capsys):
    from tests.train.blobs import blob_recording
    from tests.train.test_cli_train import TINY

    run_dir = tmp_path / "run"
    run_dir.mkdir()
    (run_dir / "config.json").write_text("{}")  # an old run: --force would remove it all
    data = blob_recording(n=30, seed=1).save(run_dir / "data.npz")
    argv = ["train", str(data), "-o", str(run_dir), "--force", "--epochs", "1", *TINY]
    code, _, err = run(argv, capsys)
    _refused(code, err, f"{run_dir} holds the input {data}")
    assert data.is_file()
