"""One set of conventions for every sub-command (issue 35), checked by walking the app.

Each sub-command is declared below as what it writes and whether it runs a model; a new
sub-command fails :func:`test_every_subcommand_is_declared` until it is, and is then checked
by every test here.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import typer.main

from lidarflow.atomic import STAMP
from lidarflow.cli import app
from lidarflow.data import read_bag, sample_bag_path
from tests.bagutil import write_bag
from tests.test_cli import run

ROOT = Path(__file__).resolve().parents[1]

#: How each writer writes OUT (an existing output: refused, or replaced with --force); {rec}: a
#: short recording, {model}: a random flownet run folder. None: too slow to run here whole
#: (the refusal, which comes first, is still checked).
WRITERS: dict[str, list[str] | None] = {
    "convert": ["convert", "{bag}", "-o", "{out}.npz"],
    "show": ["show", "{rec}", "-o", "{out}.png"],
    "simulate": ["simulate", "--frames", "3", "-o", "{out}.npz"],
    "predict": ["predict", "{rec}", "-m", "{model}", "-o", "{out}.mcap"],
    "export": ["export", "-m", "{model}", "-o", "{out}.onnx"],
    "evaluate": ["evaluate", "{rec}", "--baselines-only", "--warmup", "2", "-o", "{out}.json"],
    "demo": None,  # 3 minutes; tests/test_cli.py runs it once
    "train": None,  # its -o is a run folder: test_train_force_starts_a_run_over
    "choose-offset": None,  # its -o is a model folder: tests/evaluate/test_offsets.py
}
#: Commands that write nothing (ros1 publishes on ROS topics, live serves Foxglove).
READERS = {"info", "live", "ros1", "ros2"}
#: Commands that run a model: each takes --threads.
RUN_MODELS = {
    "demo", "predict", "evaluate", "export", "train", "choose-offset", "live", "ros1", "ros2"
}


def commands() -> dict[str, Any]:
    return dict(typer.main.get_command(app).commands)


def options(command: Any) -> dict[str, Any]:
    return {name: p for p in command.params for name in p.opts}


@pytest.fixture
def inputs(tmp_path, random_flownet_dir):
    rec = read_bag(sample_bag_path()).slice(0, 8).save(tmp_path / "in" / "short.npz")
    return {"bag": str(sample_bag_path()), "rec": str(rec), "model": str(random_flownet_dir)}


def test_every_subcommand_is_declared():
    assert set(commands()) == set(WRITERS) | READERS, "declare the new sub-command above"
    assert set(commands()) >= RUN_MODELS


@pytest.mark.parametrize("name", sorted(commands()))
def test_output_force_model_and_threads_mean_one_thing(name):
    command = commands()[name]
    opts = options(command)
    if name in WRITERS:  # every written file is named by -o/--output, overwritten by --force
        assert opts["-o"] is opts["--output"] and "--force" in opts, name
    else:
        assert "-o" not in opts and "--output" not in opts and "--force" not in opts, name
    # -m/--model is a trained model wherever it is: a path, never an architecture
    if "-m" in opts or "--model" in opts:
        assert opts["-m"] is opts["--model"], name
        assert "Path" in str(opts["--model"].type_descriptor.annotation), name
    assert ("--threads" in opts) == (name in RUN_MODELS), name


@pytest.mark.parametrize("name", sorted(commands()))
def test_help_says_what_an_option_does_in_a_line_or_two(name):
    command = commands()[name]
    assert len(command.help or "") <= 500, f"{name}: the command's help is more than a few lines"
    for param in command.params:
        text = getattr(param, "help", None) or ""
        assert len(text) <= 200, f"{name} {param.opts[0]}: {len(text)} characters of help"


def test_version_and_python_dash_m(capsys):
    from importlib.metadata import version

    code, out, _ = run(["--version"], capsys)
    assert code == 0 and out.strip() == f"lidarflow {version('lidarflow')}"
    done = subprocess.run(
        [sys.executable, "-m", "lidarflow", "--version"], capture_output=True, text=True,
        env={**os.environ, "PYTHONPATH": str(ROOT / "src")}, timeout=120,
    )  # fmt: skip
    assert done.returncode == 0 and done.stdout.strip() == out.strip()


def writer_argv(name: str, inputs: dict[str, str], stem: Path) -> tuple[list[str], Path]:
    """``name``'s command line writing ``stem`` (with the suffix it writes), and that path."""
    default = [name, *(["{rec}"] if name == "choose-offset" else []), "-o", "{out}"]
    argv = [a.format(**inputs, out=stem) for a in WRITERS[name] or default]
    return argv, Path(argv[argv.index("-o") + 1])


@pytest.mark.parametrize("name", sorted(WRITERS))
def test_an_existing_output_is_refused_in_one_line(tmp_path, capsys, name, inputs):
    argv, out = writer_argv(name, inputs, tmp_path / "old")
    kept = out
    if name in ("train", "choose-offset", "demo"):  # a folder lidarflow wrote
        out.mkdir()
        (out / STAMP).write_text("{}")
        kept = out / "model.safetensors"
    if name == "train":  # holding a run
        (out / "config.json").write_text("{}")
        argv = ["train", inputs["rec"], "-o", str(out)]
    kept.write_bytes(b"keep me")
    code, _, err = run(argv, capsys)
    assert code == 1, (name, err)
    assert err.startswith("lidarflow: error: ") and len(err.strip().splitlines()) == 1, err
    assert "--force" in err, err
    assert kept.read_bytes() == b"keep me"


@pytest.mark.parametrize("name", sorted(n for n, argv in WRITERS.items() if argv))
def test_force_replaces_the_output_and_every_file_is_renamed_into_place(
    tmp_path, capsys, monkeypatch, name, inputs
):
    argv, out = writer_argv(name, inputs, tmp_path / "out")
    out.write_bytes(b"old")
    renamed = []
    replace = os.replace

    def recording_replace(src, dst):
        renamed.append(Path(dst))
        replace(src, dst)

    monkeypatch.setattr(os, "replace", recording_replace)
    code, _, err = run(
        [*argv, "--force", *(["--threads", "1"] if name in RUN_MODELS else [])], capsys
    )
    assert code == 0, err
    assert out.read_bytes() != b"old" and out.stat().st_size > 0
    assert out in renamed  # written under another name, then renamed: never half-written
    assert not [p for p in tmp_path.rglob("*") if ".partial" in p.name]


def test_threads_default_to_one_and_can_be_set(tmp_path, capsys, monkeypatch, inputs):
    import torch

    asked = []
    monkeypatch.setattr(torch, "set_num_threads", asked.append)
    argv = ["export", "-m", inputs["model"], "-o", str(tmp_path / "a.onnx")]
    assert run(argv, capsys)[0] == 0 and asked == [1]  # a busy machine: benchmarks/bench_threads
    argv = ["export", "-m", inputs["model"], "-o", str(tmp_path / "b.onnx"), "--threads", "2"]
    assert run(argv, capsys)[0] == 0 and asked == [1, 2]
    asked.clear()
    argv = ["predict", inputs["rec"], "-m", inputs["model"], "-o", str(tmp_path / "p.mcap")]
    assert run(argv, capsys)[0] == 0 and asked == [1]


def test_train_force_starts_a_run_over(tmp_path, capsys):
    from tests.train.blobs import blob_recording

    data = blob_recording(n=30, seed=1).save(tmp_path / "blob.npz")
    run_dir = tmp_path / "run"
    tiny = ["--arch", "flownet", "--recipe", "paper", "--grid", "32", "--seq-len", "6",
            "--warmup", "2", "--batch-size", "2", "--epochs", "1", "--threads", "1",
            "--set", "runtime.tensorboard=false"]  # fmt: skip
    run_dir.mkdir()
    (run_dir / STAMP).write_text("{}")  # a run lidarflow wrote
    (run_dir / "config.json").write_text("{}")
    (run_dir / "model.safetensors").write_bytes(b"an old run")
    (run_dir / "stale.txt").write_text("from the old run")
    code, _, err = run(["train", str(data), "-o", str(run_dir), *tiny, "--force"], capsys)
    assert code == 0, err
    assert not (run_dir / "stale.txt").exists()
    assert (run_dir / "model.safetensors").read_bytes() != b"an old run"
    code, _, err = run(["train", "--resume", str(run_dir), "--force"], capsys)
    assert code == 2 and "give one" in err


def test_a_folder_that_is_not_ours_is_not_replaced_even_with_force(tmp_path, capsys, inputs):
    folder = tmp_path / "mine"
    folder.mkdir()
    (folder / "notes.txt").write_text("mine")
    argv = ["evaluate", inputs["rec"], "--baselines-only", "--report", str(folder), "--force"]
    code, _, err = run(argv, capsys)
    assert code == 1 and "not a folder lidarflow wrote" in err
    assert (folder / "notes.txt").read_text() == "mine"


def test_non_finite_weights_are_refused_when_a_model_loads(tmp_path, capsys, inputs):
    import onnx
    from onnx import numpy_helper
    from safetensors.torch import load_file, save_file

    folder = Path(inputs["model"])
    state = load_file(str(folder / "model.safetensors"))
    first = sorted(state)[0]
    state[first] = state[first].clone().fill_(float("nan"))
    bad = tmp_path / "bad"
    bad.mkdir()
    save_file(state, str(bad / "model.safetensors"))
    (bad / "model.json").write_text((folder / "model.json").read_text())
    for argv in (
        ["predict", inputs["rec"], "-m", str(bad), "-o", str(tmp_path / "p.mcap")],
        ["evaluate", inputs["rec"], "-m", str(bad), "--warmup", "2"],
        ["export", "-m", str(bad), "-o", str(tmp_path / "bad.onnx")],
    ):
        code, _, err = run(argv, capsys)
        assert code == 1 and "weights are not finite" in err and first in err, (argv[0], err)
        assert len(err.strip().splitlines()) == 1 and "internal error" not in err
    assert not (tmp_path / "bad.onnx").exists() and not (tmp_path / "p.mcap").exists()
    # an ONNX file with a NaN weight: refused by predict as it loads
    good = tmp_path / "good.onnx"
    assert run(["export", "-m", inputs["model"], "-o", str(good)], capsys)[0] == 0
    graph = onnx.load(str(good))
    weight = graph.graph.initializer[0]
    values = numpy_helper.to_array(weight).copy()
    values.flat[0] = np.inf
    weight.CopyFrom(numpy_helper.from_array(values, weight.name))
    onnx.save(graph, str(tmp_path / "nan.onnx"))
    argv = [
        "predict",
        inputs["rec"],
        "-m",
        str(tmp_path / "nan.onnx"),
        "-o",
        str(tmp_path / "q.bag"),
    ]
    code, _, err = run(argv, capsys)
    assert code == 1 and "weights are not finite" in err and weight.name in err, err


def test_info_on_a_bag_without_scans_says_so(tmp_path, capsys):
    bag = write_bag(tmp_path / "odom.bag", "ros1", {}, odom=True)
    code, out, err = run(["info", str(bag)], capsys)
    assert code == 1 and "/odom" in out  # what it holds, then why nothing more
    assert err.strip() == (
        f"lidarflow: error: {bag}: no scan topic (LaserScan or MultiEchoLaserScan) in this bag; "
        "nothing to predict on"
    )


@pytest.mark.slow
def test_a_killed_predict_leaves_neither_a_bag_nor_a_temporary(tmp_path, inputs):
    # SIGTERM (what `kill` and schedulers send) while the bag is being written
    rec = read_bag(sample_bag_path()).save(tmp_path / "long.npz")
    before = sorted(p.name for p in tmp_path.iterdir())
    out = tmp_path / "out.bag"
    proc = subprocess.Popen(
        [sys.executable, "-m", "lidarflow", "predict", str(rec), "-m", inputs["model"],
         "-o", str(out)],
        env={**os.environ, "PYTHONPATH": str(ROOT / "src"), "OMP_NUM_THREADS": "1"},
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    deadline = time.monotonic() + 240
    while not [p for p in tmp_path.iterdir() if ".partial" in p.name]:
        assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
        time.sleep(0.05)
    time.sleep(0.5)  # some scans written
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130 and "interrupted" in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == before
