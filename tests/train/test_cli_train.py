"""``lidarflow train`` from the command line: help, a run, resume, and one-line errors."""

from __future__ import annotations

import json

import pytest

from lidarflow.cli import main

TINY = [
    "--grid",
    "32",
    "--seq-len",
    "8",
    "--warmup",
    "3",
    "--batch-size",
    "3",
    "--val-fraction",
    "0.25",
    "--set",
    "runtime.tensorboard=false",
    "--threads",
    "1",
]


def run_cli(args, capsys):
    with pytest.raises(SystemExit) as exc:
        main(args)
    out = capsys.readouterr()
    return exc.value.code, out.out, out.err


def test_help_explains_the_options(capsys):
    code, out, _ = run_cli(["train", "--help"], capsys)
    assert code == 0
    for option in (
        "--arch",
        "--recipe",
        "--resume",
        "--no-gaussian",
        "--mix",
        "--set",
        "--amp",
        "--val-fraction",
        "torchrun",
    ):
        assert option in out


@pytest.mark.slow
def test_train_then_resume_to_more_epochs(blob_files, tmp_path, capsys):
    run = tmp_path / "run"
    code, out, err = run_cli(
        [
            "train",
            *map(str, blob_files),
            "-o",
            str(run),
            "--recipe",
            "paper",
            "--epochs",
            "1",
            "--no-gaussian",
            "--lr",
            "0.003",
            "--mix",
            "0.75",
            *TINY,
        ],
        capsys,
    )
    assert code in (0, None), err
    assert "model.safetensors" in out
    cfg = json.loads((run / "config.json").read_text())
    assert cfg["schedule"]["gaussian"] is False and cfg["data"]["mix"] == [0.75]
    assert cfg["optim"]["lr"] == 0.003 and cfg["recipe"] == "paper"
    assert not (run / "training.lock").exists()  # released when the run ends
    resume = ["train", "--resume", str(run), "--epochs", "2"]
    code, _, err = run_cli([*resume, "--set", "optim.lr=0.1"], capsys)
    assert code == 2 and "--set optim.lr=0.1" in err  # what it computes may not change
    code, out, err = run_cli([*resume, "--set", "runtime.threads=1"], capsys)  # how it runs may
    assert code in (0, None), err
    rows = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
    assert [r["epoch"] for r in rows] == [0, 1, 2]
    assert [r["gaussian_size"] for r in rows[1:]] == [1, 1]
    assert json.loads((run / "config.json").read_text())["optim"]["epochs"] == 2  # extended


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--lr", "1e30", "--epochs", "2"], "training diverged at epoch 1, step 2"),
        (["--set", "optim.nope=1"], "unknown setting 'optim.nope'"),
        (["--arch", "resnet"], "model.name must be one of"),
    ],
)
def test_failures_are_one_line_with_exit_1(blob_files, tmp_path, capsys, extra, message):
    code, _, err = run_cli(
        [
            "train",
            str(blob_files[0]),
            "-o",
            str(tmp_path / "r"),
            "--recipe",
            "paper",
            *TINY,
            *extra,
        ],
        capsys,
    )
    assert code == 1
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("lidarflow: error: ") and message in lines[0]
    assert "Traceback" not in err


def test_a_run_folder_is_trained_by_one_process_on_its_own_data(blob_files, tmp_path, capsys):
    import socket
    import subprocess

    data = tmp_path / "a.npz"
    data.write_bytes(blob_files[0].read_bytes())
    run, folder = ["train", str(data), "--recipe", "paper", "--epochs", "1", *TINY], tmp_path / "r"
    folder.mkdir()
    other = subprocess.Popen(["sleep", "60"])  # another live process holding the folder
    try:
        lock = {"pid": other.pid, "host": socket.gethostname()}
        (folder / "training.lock").write_text(json.dumps(lock))
        code, _, err = run_cli([*run, "-o", str(folder)], capsys)
        assert code == 1 and f"being trained by process {other.pid}" in err, err
    finally:
        other.kill()
        other.wait()
    code, _, err = run_cli([*run, "-o", str(folder)], capsys)  # a stale lock is taken over
    assert code in (0, None), err
    # one left on another machine too (a run copied here, a job requeued elsewhere)
    (folder / "training.lock").write_text(json.dumps({"pid": 1, "host": "another-node"}))
    code, _, err = run_cli(["train", "--resume", str(folder), "--set", "optim.epochs=2"], capsys)
    assert code in (0, None), err
    assert not (folder / "training.lock").exists()
    with data.open("ab") as f:  # the recording at that path is no longer the one trained on
        f.write(b"0" * 10)
    code, _, err = run_cli(["train", "--resume", str(folder), "--epochs", "3"], capsys)
    assert code == 1 and "changed since the run started" in err, err


def test_resume_refuses_new_settings_and_needs_a_run(tmp_path, capsys):
    code, _, err = run_cli(["train", "--resume", str(tmp_path), "--lr", "0.1"], capsys)
    assert code == 2 and "a resumed run keeps its config" in err  # usage error
    code, _, err = run_cli(["train", "--resume", str(tmp_path)], capsys)
    assert code == 1 and "not a training run (no config.json)" in err
    code, _, err = run_cli(["train", "x.npz"], capsys)
    assert code == 2 and "-o RUN_DIR" in err
    code, _, err = run_cli(["train", "-o", str(tmp_path / "r")], capsys)
    assert code == 2 and "give training data" in err


@pytest.mark.slow
def test_trains_on_a_bag_directly_mixed_with_a_recording(blob_files, tmp_path, capsys):
    from lidarflow.data import SAMPLE_TOPIC, sample_bag_path

    run = tmp_path / "mixed"
    args = [
        "train",
        str(sample_bag_path()),
        str(blob_files[0]),
        "--topic",
        SAMPLE_TOPIC,
        "--mix",
        "0.5",
        "--arch",
        "deeptracking",
        "--epochs",
        "1",
        "-o",
        str(run),
        *TINY,
    ]
    code, out, err = run_cli(args, capsys)
    assert code in (0, None), err
    record = json.loads((run / "model.json").read_text())
    assert record["model"] == "deeptracking"
    assert record["training"]["sources"] == [str(sample_bag_path()), str(blob_files[0])]
    assert "weight 0.50" in out


@pytest.mark.parametrize("section", ['"flownet"', "1"])
def test_a_config_whose_model_is_no_table_is_one_line(tmp_path, capsys, section):
    # the default recipe's look-up of model.name raised AttributeError, an "internal error"
    config = tmp_path / "c.json"
    config.write_text(f'{{"model": {section}}}')
    code, _, err = run_cli(
        ["train", "x.npz", "-o", str(tmp_path / "r"), "--config", str(config)], capsys
    )
    assert code == 1 and err.startswith("lidarflow: error: config model: expected a table")


def test_resume_cannot_shorten_a_run(tmp_path, capsys):
    from lidarflow.train.config_io import build_config, config_to_dict

    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    (tmp_path / "x.npz").touch()  # a resume needs its recordings where they were
    config = build_config("paper", None, {"data.sources": [str(tmp_path / "x.npz")]})
    (run / "config.json").write_text(json.dumps(config_to_dict(config)))
    (run / "checkpoints" / "latest.json").write_text('{"epoch": 3}')
    code, _, err = run_cli(["train", "--resume", str(run), "--epochs", "2"], capsys)
    assert code == 1 and "has trained 3 epochs; --epochs 2 cannot shorten it" in err
    # config.json (and so model.json) still says how many epochs the weights had
    assert json.loads((run / "config.json").read_text())["optim"]["epochs"] == 200


def test_ctrl_c_says_how_to_resume(blob_files, tmp_path, capsys, monkeypatch):
    import lidarflow.train.loop

    run = tmp_path / "run"

    def interrupted_after_two_epochs(*args, **kwargs):
        (run / "checkpoints").mkdir(parents=True)
        (run / "checkpoints" / "latest.json").write_text('{"epoch": 2}')
        raise KeyboardInterrupt

    monkeypatch.setattr(lidarflow.train.loop, "train", interrupted_after_two_epochs)
    code, _, err = run_cli(["train", str(blob_files[0]), "-o", str(run)], capsys)
    # typer used to turn Ctrl-C into a silent exit 130
    assert code == 130 and err.strip() == (
        f"lidarflow: interrupted: `lidarflow train --resume {run}` continues {run} after epoch 2"
    )


@pytest.mark.slow
def test_a_killed_run_resumes_from_its_last_epoch(blob_files, tmp_path, capsys):
    import os
    import signal
    import subprocess
    import sys
    import time
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    run = tmp_path / "killed"
    env = {**os.environ, "PYTHONPATH": str(root / "src"), "OMP_NUM_THREADS": "1"}
    cmd = [
        sys.executable,
        "-m",
        "lidarflow.cli",
        "train",
        str(blob_files[0]),
        "-o",
        str(run),
        "--epochs",
        "500",
        "--recipe",
        "paper",
        *TINY,
    ]
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    pointer = run / "checkpoints" / "latest.json"
    deadline = time.monotonic() + 60
    try:
        while time.monotonic() < deadline and proc.poll() is None:
            if pointer.exists() and json.loads(pointer.read_text())["epoch"] >= 1:
                break
            time.sleep(0.05)
    finally:
        os.kill(proc.pid, signal.SIGKILL)  # no clean-up, possibly mid-write
        proc.wait()
    done = json.loads(pointer.read_text())["epoch"]
    assert done >= 1, proc.stderr.read().decode()[-2000:]
    code, _, err = run_cli(["train", "--resume", str(run), "--epochs", str(done + 1)], capsys)
    assert code in (0, None), err
    rows = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
    assert [r["epoch"] for r in rows] == list(range(done + 2))
    assert not list(run.glob("**/.*.tmp"))  # what the kill left half-written is gone


def test_default_recipe_trains_the_bundled_head_without_a_flow_network(
    tmp_path, blob_files, capsys
):
    import torch
    from safetensors.torch import load_file

    from lidarflow.models.presets import resolve_model

    run = tmp_path / "head_only"
    args = ["train", *map(str, blob_files), "-o", str(run), *TINY]  # no --recipe: head_only
    code, out, err = run_cli([*args, "--epochs", "1", "--set", "data.epoch_windows=6"], capsys)
    assert code in (0, None), err
    assert "starting from the weights of bundled" in out
    config = json.loads((run / "config.json").read_text())
    assert config["recipe"] == "head_only" and config["model"]["init"] == "bundled"
    record = json.loads((run / "model.json").read_text())
    assert record["model_kwargs"]["poses_optional"] and not record["model_kwargs"]["flow_network"]
    assert record["decision"] == {"offset": 0.0, "online": True, "movers": True}  # the recipe's
    trained = load_file(run / "model.safetensors")
    bundled = resolve_model("bundled")[0].state_dict()
    assert set(trained) == set(bundled) and not any(".flow." in k for k in trained)
    # the bundled head, trained on: every input of the head recipe's (the current map, five
    # memories, the constant-velocity map, the visibility map and the two sub-cell channels)
    head = trained["inner.head.out.weight"]
    assert (head - bundled["inner.head.out.weight"]).abs().max() > 1e-3
    assert trained["inner.head.hidden.weight"].shape[1:] == (1 + 5 + 1 + 1 + 2, 1, 1)
    assert all(torch.isfinite(v).all() for v in trained.values())


def test_the_head_recipe_trains_a_head_on_a_given_flow_network(tmp_path, blob_files, capsys):
    import torch
    from safetensors.torch import load_file

    from lidarflow.models.presets import resolve_model
    from tests.conftest import FLOW_MODEL

    run = tmp_path / "head"
    args = ["train", *map(str, blob_files), "-o", str(run), *TINY, "--recipe", "head"]
    # the bundled model has no flow network since v9: the recipe's default start is refused
    code, _, err = run_cli([*args, "--epochs", "1"], capsys)
    assert code == 1 and "has no flow network" in err and "--init" in err, err
    assert len(err.strip().splitlines()) == 1
    code, _, err = run_cli(
        [*args, "--init", str(FLOW_MODEL), "--epochs", "1", "--set", "data.epoch_windows=6"],
        capsys,
    )
    assert code in (0, None), err

    # The recipe compensates ego motion (a wrapper: every name gets "inner.").
    def unwrapped(weights: dict) -> dict:
        return {k.removeprefix("inner."): v for k, v in weights.items()}

    trained = unwrapped(load_file(run / "model.safetensors"))
    given = unwrapped(resolve_model(FLOW_MODEL)[0].state_dict())  # the file has v8's names
    # The flow network is the given one (lr 1e-6: moved by about 1e-6 per step) ...
    flow = given["flow.conv_flow.weight"]
    assert flow.abs().max() > 1e-3  # a trained flow head, not zero
    torch.testing.assert_close(trained["flow.conv_flow.weight"], flow, atol=1e-4, rtol=0)
    # ... the head (the given one: the same inputs) has learnt.
    head, before = trained["head.out.weight"], given["head.out.weight"]
    assert (head - before).abs().max() > 1e-3
    assert trained["head.hidden.weight"].shape[1:] == (1 + 5 + 1 + 1 + 2, 1, 1)


def test_a_config_file_naming_deeptracking_gets_the_papers_recipe(tmp_path, blob_files, capsys):
    # No --recipe and no --model: the default recipe follows the model the config file names.
    config = tmp_path / "dt.json"
    config.write_text(json.dumps({"model": {"name": "deeptracking"}}))
    run = tmp_path / "dt"
    args = ["train", str(blob_files[0]), "--config", str(config), "-o", str(run), *TINY]
    code, _, err = run_cli([*args, "--epochs", "1", "--set", "data.epoch_windows=2"], capsys)
    assert code in (0, None), err
    saved = json.loads((run / "config.json").read_text())
    assert saved["recipe"] == "paper" and saved["model"]["name"] == "deeptracking"


@pytest.mark.slow
def test_a_run_copied_elsewhere_resumes_on_its_recordings_found_again(blob_files, tmp_path, capsys):
    here, there = tmp_path / "robot", tmp_path / "workstation"
    here.mkdir()
    data, val = here / "a.npz", here / "v.npz"
    data.write_bytes(blob_files[0].read_bytes())
    val.write_bytes(blob_files[1].read_bytes())
    train = ["train", "--recipe", "paper", *TINY]
    first = [*train, str(data), "--val", str(val), "--epochs", "1", "-o", str(here / "run")]
    code, _, err = run_cli(first, capsys)
    assert code in (0, None), err
    here.rename(there)  # the recorded absolute paths are gone
    run = there / "run"
    code, _, err = run_cli(["train", "--resume", str(run), "--epochs", "2"], capsys)
    assert code == 1 and "give the recordings again" in err, err
    other = there / "b.npz"
    other.write_bytes((there / "a.npz").read_bytes())
    code, _, err = run_cli(["train", str(other), "--resume", str(run), "--epochs", "2"], capsys)
    assert code == 1 and "was trained on" in err  # another name: not the same recording
    again = ["train", str(there / "a.npz"), "--resume", str(run), "--epochs", "2"]
    code, _, err = run_cli(again, capsys)
    assert code == 1 and "--val V... --resume" in err, err  # its validation recording too
    code, _, err = run_cli([*again, "--val", str(there / "v.npz")], capsys)
    assert code in (0, None), err
    rows = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
    assert rows[-1]["epoch"] == 2
    assert json.loads((run / "config.json").read_text())["data"]["sources"] == [
        str(there / "a.npz")
    ]


@pytest.mark.slow
def test_a_time_budget_ends_the_run_after_an_epoch_and_resume_continues(
    blob_files, tmp_path, capsys
):
    run = tmp_path / "run"
    first = ["train", *map(str, blob_files), "-o", str(run), "--recipe", "paper", "--epochs", "3"]
    code, out, err = run_cli([*first, "--max-minutes", "0.0001", *TINY], capsys)
    assert code in (0, None), err
    assert "time budget of 0.0001 min spent" in out + err
    card = json.loads((run / "model.json").read_text())
    assert card["training"]["epochs"] == 3 and card["training"]["epochs_done"] == 1
    epochs = [
        json.loads(line)["epoch"] for line in (run / "metrics.jsonl").read_text().splitlines()
    ]
    assert max(epochs) == 1
    # the budget is how the run executes: lifted on resume, the run goes on to its epochs
    code, out, err = run_cli(["train", "--resume", str(run), "--max-minutes", "0"], capsys)
    assert code in (0, None), err
    card = json.loads((run / "model.json").read_text())
    assert card["training"]["epochs_done"] == 3


def test_a_negative_time_budget_is_refused_in_one_line(blob_files, tmp_path, capsys):
    code, _, err = run_cli(
        ["train", str(blob_files[0]), "-o", str(tmp_path / "r"), "--max-minutes", "-1"], capsys
    )
    assert code == 2 and "Traceback" not in err
