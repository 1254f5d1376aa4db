"""The training loop on tiny data: run files, exact resume, divergence detection."""

from __future__ import annotations

import json

import pytest
import torch
from safetensors.torch import load_file, save_file

import lidarflow.train.model_setup as model_setup
import lidarflow.train.objective as objective
import lidarflow.train.precision as precision
from lidarflow.errors import EvaluateError, TrainError
from lidarflow.models import ModelSpec, build_model
from lidarflow.scan import GridSpec
from lidarflow.train import build_config, train
from lidarflow.train.checkpoint import latest_epoch
from lidarflow.train.config_io import config_from_dict


def tiny_config(sources, recipe="blurred", **flags):
    base = {
        "data.sources": [str(s) for s in sources],
        "data.grid": 32,
        "data.seq_len": 8,
        "data.warmup": 3,
        "data.val_fraction": 0.25,
        "optim.batch_size": 3,
        "optim.epochs": 2,
        "optim.lr": 0.003,
        "runtime.tensorboard": False,
        "runtime.threads": 1,
    }
    return build_config(recipe, None, {**base, **flags})


class KilledError(Exception):
    pass


@pytest.mark.slow
def test_short_training_writes_its_files(blob_files, tmp_path, monkeypatch):
    # HEAD moves during the run: model.json names the commit the run started at (run.json's).
    commits = iter(["started-here", "moved-on"])
    monkeypatch.setattr("lidarflow.train.rundir._git_commit", lambda: next(commits, "later"))
    cfg = tiny_config(
        blob_files, **{"schedule.gaussian_step_epochs": 1, "schedule.lr_step_epochs": 1}
    )
    result = train(cfg, tmp_path / "run")
    run = tmp_path / "run"
    for name in (
        "config.json",
        "run.json",
        "metrics.csv",
        "metrics.jsonl",
        "last.safetensors",
        "best.safetensors",
        "model.safetensors",
        "model.json",
    ):
        assert (run / name).is_file(), name
    assert config_from_dict(json.loads((run / "config.json").read_text())) == cfg
    rows = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
    assert [r["epoch"] for r in rows] == [0, 1, 2]  # 0: the untrained net
    assert [r["gaussian_size"] for r in rows[1:]] == [9, 7]
    assert [r["lr"] for r in rows[1:]] == pytest.approx([0.003, 0.0015])
    assert rows[0]["val_f1"] == pytest.approx(rows[0]["val_copy_last_f1"])  # zero flow = copy
    assert all(r["train_loss"] > 0 and r["frame_steps_per_s"] > 0 for r in rows[1:])
    assert "val_epe" in rows[-1] and "val_epe_moving" in rows[-1]
    header = (run / "metrics.csv").read_text().splitlines()[0].split(",")
    assert {"epoch", "train_loss", "val_loss", "val_f1", "val_copy_last_f1", "val_epe"} <= set(
        header
    )
    record = json.loads((run / "model.json").read_text())
    assert record["model"] == "flownet" and record["parameters"] == 42_500
    assert json.loads((run / "run.json").read_text())["commit"] == "started-here"
    assert record["training"]["commit"] == "started-here"
    assert record["grid"] == {"height": 32, "width": 32, "res": 0.1}
    assert latest_epoch(run) == 2
    net = build_model(record["model"], **record["model_kwargs"])
    net.load_state_dict(load_file(run / "model.safetensors"))
    for key, value in result.model.state_dict().items():
        assert torch.equal(net.state_dict()[key], value)
    with pytest.raises(TrainError, match="already holds a training run"):
        train(cfg, run)


def test_deeptracking_trains_with_its_own_loss(blob_files, tmp_path):
    flags = {"model.name": "deeptracking", "optim.epochs": 1, "data.val_fraction": 0.0}
    result = train(tiny_config(blob_files[:1], **flags), tmp_path / "dt")
    record = json.loads((tmp_path / "dt" / "model.json").read_text())
    assert record["model"] == "deeptracking" and record["out_channels"] == 1
    # no validation: no epoch-0 row, no val metrics, "best" falls back to the training loss
    assert [r["epoch"] for r in result.rows] == [1]
    assert result.rows[0]["train_loss"] > 0 and "val_loss" not in result.rows[0]
    assert record["training"]["best"]["metric"] == "-train_loss"


@pytest.mark.slow
def test_resume_continues_exactly(blob_files, tmp_path):
    flags = {
        "optim.epochs": 3,
        "schedule.lr_step_epochs": 1,
        "schedule.gaussian_step_epochs": 1,
        "optim.lr": 0.01,
    }
    straight = train(tiny_config(blob_files, **flags), tmp_path / "a")

    def kill_after_first(epoch, row):
        if epoch == 1:
            raise KilledError

    with pytest.raises(KilledError):
        train(tiny_config(blob_files, **flags), tmp_path / "b", on_epoch_end=kill_after_first)
    assert latest_epoch(tmp_path / "b") == 1 and not (tmp_path / "b" / "model.safetensors").exists()
    resumed = train(tiny_config(blob_files, **flags), tmp_path / "b", resume=True)
    a = load_file(tmp_path / "a" / "model.safetensors")
    b = load_file(tmp_path / "b" / "model.safetensors")
    assert a.keys() == b.keys()
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert any(not torch.equal(a[k], torch.zeros_like(a[k])) for k in a if "conv_flow" in k)
    strip = ("train_seconds", "frame_steps_per_s")
    rows_a = [{k: v for k, v in r.items() if k not in strip} for r in straight.rows]
    rows_b = [{k: v for k, v in r.items() if k not in strip} for r in resumed.rows]
    assert rows_a == rows_b  # losses, lr, Gaussian size and metrics of every epoch
    with pytest.raises(TrainError, match=r"cannot resume with a different config \(optim changed"):
        train(tiny_config(blob_files, **{**flags, "optim.lr": 0.5}), tmp_path / "b", resume=True)


@pytest.mark.slow
def test_a_spent_time_budget_ends_the_run_after_an_epoch_and_resume_goes_on(blob_files, tmp_path):
    cfg = tiny_config(blob_files, **{"runtime.max_minutes": 1e-9, "optim.epochs": 3})
    said: list[str] = []
    result = train(cfg, tmp_path / "run", echo=said.append)
    assert [r["epoch"] for r in result.rows] == [0, 1]  # the untrained row, then epoch 1
    assert latest_epoch(tmp_path / "run") == 1
    assert (tmp_path / "run" / "model.safetensors").is_file()  # ended, not failed: usable
    assert any("time budget" in m and "after epoch 1 of 3 (--resume" in m for m in said)
    result = train(cfg, tmp_path / "run", resume=True)
    assert [r["epoch"] for r in result.rows] == [0, 1, 2]
    said.clear()
    result = train(cfg, tmp_path / "run", resume=True, echo=said.append)
    assert [r["epoch"] for r in result.rows] == [0, 1, 2, 3]
    assert not any("time budget" in m for m in said)  # the last epoch ends the run anyway


@pytest.mark.slow
def test_final_weights_best_writes_the_best_epoch_as_the_model(blob_files, tmp_path):
    cfg = tiny_config(blob_files, **{"runtime.final_weights": "best", "optim.epochs": 3})
    result = train(cfg, tmp_path / "run")
    model = load_file(tmp_path / "run" / "model.safetensors")
    best = load_file(tmp_path / "run" / "best.safetensors")
    last = load_file(tmp_path / "run" / "last.safetensors")
    assert result.extra["best"]["epoch"] < 3  # here the best is not the last: they differ
    assert all(torch.equal(model[k], best[k]) for k in best)
    assert any(not torch.equal(model[k], last[k]) for k in last)
    record = json.loads((tmp_path / "run" / "model.json").read_text())
    assert record["training"]["best"] == result.extra["best"]


def test_non_finite_loss_stops_and_saves_nothing_corrupt(blob_files, tmp_path, monkeypatch):
    from lidarflow.train import objective

    real = objective.flow_loss
    calls = {"n": 0}

    def poisoned(seq, flows, kernel_size, config, warmup=10):
        loss = real(seq, flows, kernel_size, config, warmup)
        calls["n"] += 1
        return loss * float("nan") if calls["n"] == 7 else loss

    monkeypatch.setattr(objective, "flow_loss", poisoned)
    cfg = tiny_config(blob_files, **{"runtime.eval_before_training": False, "optim.epochs": 3})
    # per epoch: 10 training windows in batches of 3 (4 steps) + 1 validation batch = 5 calls
    with pytest.raises(TrainError, match=r"epoch 2, step 2 of 4 .*non-finite .*loss nan"):
        train(cfg, tmp_path / "run")
    run = tmp_path / "run"
    assert latest_epoch(run) == 1
    rows = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
    assert [r["epoch"] for r in rows] == [1]
    assert not (run / "model.safetensors").exists()
    weights = load_file(run / "last.safetensors")
    assert all(torch.isfinite(v).all() for v in weights.values())


@pytest.mark.slow
def test_bf16_autocast_and_channels_last_train_in_fp32_weights(blob_files, tmp_path):
    cfg = tiny_config(
        blob_files[:1],
        **{"optim.epochs": 1, "runtime.amp": "bf16", "runtime.channels_last": True},
    )
    result = train(cfg, tmp_path / "bf16")
    row = result.rows[-1]
    assert all(v == v for v in row.values())  # no NaN anywhere
    assert 0 < row["train_loss"] < 1 and 0 < row["val_loss"] < 1
    weights = load_file(tmp_path / "bf16" / "model.safetensors")
    assert {v.dtype for v in weights.values()} == {torch.float32}


@pytest.mark.parametrize("native", [True, False])
def test_amp_auto_takes_bf16_only_where_the_device_has_it(monkeypatch, native):
    monkeypatch.setattr(precision, "native_bf16", lambda device: native)
    cpu = torch.device("cpu")
    bf16, note = precision.resolve_amp("auto", cpu)
    assert bf16 is native
    assert note is not None and ("bf16 autocast" if native else "fp32") in note
    assert precision.resolve_amp("none", cpu) == (False, None)
    # bf16 asked for by name is kept, but where it is emulated the log says what it costs.
    bf16, note = precision.resolve_amp("bf16", cpu)
    assert bf16 and (note is None) is native
    if not native:
        assert "emulated" in note and "--amp auto" in note


def test_amp_auto_says_its_choice_in_the_training_log(blob_files, tmp_path, monkeypatch):
    monkeypatch.setattr(precision, "native_bf16", lambda device: False)
    cfg = tiny_config(blob_files[:1], **{"optim.epochs": 1, "runtime.amp": "auto"})
    said: list[str] = []
    train(cfg, tmp_path / "auto", echo=said.append)
    assert any(line.startswith("amp auto: fp32") for line in said), said
    with pytest.raises(TrainError, match=r"runtime\.amp must be one of none, bf16, auto"):
        train(tiny_config(blob_files[:1], **{"runtime.amp": "fp16"}), tmp_path / "fp16")


#: A head fitted by cross-entropy on a fresh flow network (the head recipe starts from trained
#: weights, frozen).
HEAD = {"loss.occupancy_bce": 1.0, "model.kwargs": {"occupancy_head": True}}


def test_a_head_trains_by_cross_entropy_and_needs_one(blob_files, tmp_path):
    flags = {"data.stride": 0, "data.epoch_windows": 0, "data.val_fraction": 0.0}
    cfg = tiny_config(blob_files[:1], **HEAD, **flags, **{"optim.epochs": 1})
    result = train(cfg, tmp_path / "res")
    gain = result.model.warp_gain()
    assert gain != pytest.approx(build_model("flownet", occupancy_head=True).warp_gain())
    record = json.loads((tmp_path / "res" / "model.json").read_text())
    assert record["out_channels"] == 5 and record["model_kwargs"]["occupancy_head"]
    assert record["decision"] == {"offset": 0.0, "online": False, "movers": False}
    without_head = build_config("blurred", None, {"loss.occupancy_bce": 1.0})
    with pytest.raises(TrainError, match="occupancy head"):
        objective.make_loss(without_head, 1, build_model("flownet"))


def test_init_starts_from_given_weights(blob_files, tmp_path):
    first = train(tiny_config(blob_files[:1], **{"optim.epochs": 1}), tmp_path / "a")
    cfg = tiny_config(blob_files[:1], **{"optim.epochs": 1, "model.init": str(tmp_path / "a")})
    cfg.runtime.eval_before_training = True
    second = train(cfg, tmp_path / "b")
    # epoch 0 of the second run evaluates the first run's weights, not a fresh copy-last net
    assert second.rows[0]["val_loss"] == pytest.approx(first.rows[-1]["val_loss"])
    assert second.rows[0]["val_loss"] != pytest.approx(first.rows[0]["val_loss"])
    # A head model may start from a plain flow model: flow copied, head at its copy-last start.
    model = build_model("flownet", occupancy_head=True)
    fresh_head = {k: v.clone() for k, v in model.state_dict().items() if k.startswith("head.")}
    assert model_setup.load_init(model, str(tmp_path / "a")) is True
    for name, value in first.model.state_dict().items():
        assert torch.equal(model.state_dict()[name], value), name
    for name, value in fresh_head.items():
        assert torch.equal(model.state_dict()[name], value), name
    # The other way round (weights the model has no place for) is refused.
    with pytest.raises(TrainError, match="cannot start from these weights"):
        model_setup.load_init(build_model("deeptracking"), str(tmp_path / "a"))


def test_a_head_of_other_inputs_starts_afresh_on_the_copied_flow(tmp_path):
    from tests.conftest import make_model_dir

    source = make_model_dir(tmp_path / "head", occupancy_head=True, zero_init_flow=False)
    weights = load_file(source / "model.safetensors")
    for name in ("head.out.bias", "head.gain"):  # a trained-looking head: copying shows
        weights[name] = weights[name] + 1.0
    save_file(weights, source / "model.safetensors")
    model = build_model("flownet", occupancy_head=True, constant_velocity_input=True)
    fresh_head = {k: v.clone() for k, v in model.state_dict().items() if model_setup.is_head(k)}
    assert model_setup.load_init(model, str(source)) is True
    for name, value in model.state_dict().items():
        expected = fresh_head[name] if model_setup.is_head(name) else weights[name]
        assert torch.equal(value, expected), name
    assert model.flow.conv_flow.weight.abs().sum() > 0


def test_head_learning_rate_scale_applies_to_the_head_only():
    cfg = build_config("head", None, {"optim.lr": 0.002, "optim.head_lr_scale": 10.0})
    model = build_model("flownet", occupancy_head=True)
    optimizer = model_setup.make_optimizer(cfg, model)
    rest, head = optimizer.param_groups
    assert rest["lr"] == pytest.approx(0.002) and head["lr"] == pytest.approx(0.02)
    head_ids = {id(p) for p in head["params"]}
    assert head_ids == {id(model.head.gain), *(id(p) for p in model.head.out.parameters())}
    assert len(rest["params"]) + len(head["params"]) == len(list(model.parameters()))
    # Models without a head keep one group: resuming their old checkpoints still works.
    plain = build_model("flownet")
    assert len(model_setup.parameter_groups(plain, cfg)) == 1
    with pytest.raises(TrainError, match="head_lr_scale"):
        build_config("head", None, {"optim.head_lr_scale": 0.0})


def test_ego_motion_models_start_from_plain_ones_and_back(tmp_path):
    # The wrapper has no weight of its own; only its "inner." prefix differs.
    from tests.conftest import make_model_dir

    plain = make_model_dir(tmp_path / "plain", occupancy_head=True, zero_init_flow=False)
    weights = load_file(plain / "model.safetensors")
    ego = build_model("flownet", occupancy_head=True, ego_motion=True, poses_optional=True)
    assert model_setup.load_init(ego, str(plain)) is False  # nothing left new
    for name, value in weights.items():
        assert torch.equal(ego.state_dict()["inner." + name], value), name
    folder = tmp_path / "ego"
    folder.mkdir()
    state = {k: v.contiguous() for k, v in ego.state_dict().items()}
    save_file(state, folder / "model.safetensors")
    kwargs = ModelSpec.from_kwargs("flownet", {"occupancy_head": True, "ego_motion": True})[0]
    card = {"model": "flownet", "model_kwargs": kwargs.to_kwargs()}
    (folder / "model.json").write_text(json.dumps(card))
    back = build_model("flownet", occupancy_head=True)
    assert model_setup.load_init(back, str(folder)) is False
    for name, value in weights.items():
        assert torch.equal(back.state_dict()[name], value), name


def test_a_subcell_model_trains_validates_and_evaluates(blob_files, tmp_path):
    from lidarflow.data import load_any
    from lidarflow.evaluate.model_method import ModelMethod
    from lidarflow.evaluate.runner import evaluate_recording

    kwargs = {"occupancy_head": True, "subcell_input": True}
    flags = {**HEAD, "optim.epochs": 1, "model.kwargs": kwargs}
    result = train(tiny_config(blob_files[:1], **flags), tmp_path / "sub")
    head = result.model.head.out.weight[0, -2:]  # the edge and near inputs' weights
    assert head.abs().max() > 0  # trained: the loss reached them
    method = ModelMethod("sub", result.model)
    recording = load_any(blob_files[1])
    scores = evaluate_recording(recording, [method], GridSpec(32, 32, 0.1))
    assert scores["sub"].summary()["f1"] > 0
    with pytest.raises(EvaluateError, match="subcell_input"):
        method.update(*(m[0] for m in recording.maps(GridSpec(32, 32, 0.1))))
