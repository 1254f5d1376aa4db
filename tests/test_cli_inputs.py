"""Issue 51: input that is at fault is said to be, in one line naming the option or file (not
an internal error, not gigabytes asked of PyTorch, not an exit 0 with nonsense)."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from lidarflow.scan import MAX_RES
from tests.bagutil import MCAP_MAGIC, _mcap_record, _mcap_string, write_bag
from tests.test_cli import run
from tests.test_cli_faults import one_line


@pytest.mark.parametrize(
    "argv",
    [
        ["predict", "{rec}", "-o", "{out}/p.mcap", "--res", "1e300"],
        ["evaluate", "{rec}", "--baselines-only", "--res", "1e300"],
        ["simulate", "--frames", "3", "-o", "{out}/s.npz", "--res", "1e300"],
        ["show", "{rec}", "-o", "{out}/s.png", "--res", "1e300"],
        ["convert", "{rec}", "-o", "{out}/c.npz", "--res", "1e300"],
        ["choose-offset", "{rec}", "-o", "{out}/m", "--res", "1e300"],
        ["train", "{rec}", "-o", "{out}/run", "--res", "1e300", "--epochs", "1"],
    ],
)
def test_a_cell_size_beyond_reason_is_refused(argv, short, tmp_path, capsys):
    out = tmp_path / "out"
    code, _, err = run([a.format(rec=short, out=out) for a in argv], capsys)
    line = one_line(err)
    assert code == 1 and "--res" in line and "1e+300 m" in line, line
    assert f"at most {MAX_RES:g} m" in line, line
    assert not out.exists() or not any(out.iterdir())


def test_a_negative_seed_is_refused(short, tmp_path, capsys):
    code, _, err = run(["simulate", "--frames", "3", "-o", str(tmp_path / "s.npz"), "--seed", "-1"],
                       capsys)  # fmt: skip
    line = one_line(err)
    assert code == 1 and "seed (--seed) must be >= 0, got -1" in line, line
    argv = ["train", str(short), "-o", str(tmp_path / "run"), "--seed", "-1", "--epochs", "1"]
    code, _, err = run(argv, capsys)
    line = one_line(err)
    assert code == 1 and "runtime.seed (--seed)" in line, line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["short.npz"]


@pytest.mark.parametrize("offset", ["nan", "inf", "-inf", "1e9"])
def test_choose_offset_refuses_an_offset_that_is_no_number(offset, short, tmp_path, capsys):
    out = tmp_path / "chosen"
    code, _, err = run(["choose-offset", str(short), "-o", str(out), "--offset", offset], capsys)
    line = one_line(err)
    assert code == 1 and "--offset" in line and "[-20, 20]" in line, line
    assert not out.exists()


def _edit_card(folder, edit) -> None:
    card = json.loads((folder / "model.json").read_text())
    edit(card)
    (folder / "model.json").write_text(json.dumps(card))


@pytest.mark.parametrize(
    ("edit", "says"),
    [
        (
            lambda c: c["model_kwargs"].update(occupancy_head=True, head_hidden_channels=1e9),
            "head_hidden_channels must be a whole number in [0, 1024]",
        ),
        (
            lambda c: c["model_kwargs"].update(hidden_channels=10**6),
            "hidden_channels must be a whole number in [1, 1024]",
        ),
        (
            lambda c: c["model_kwargs"].update(hidden_channels=10**400),  # no float holds it
            "hidden_channels must be a whole number in [1, 1024]",
        ),
        (lambda c: c["model_kwargs"].update(dilations=[1, 2, 1e6]), "dilations must be"),
        (lambda c: c["model_kwargs"].update(kernel_size=float("nan")), "kernel_size must be"),
        (lambda c: c["decision"].update(offset=float("nan")), "decision.offset: the decision"),
        (lambda c: c["decision"].update(offset=float("inf")), "decision.offset: the decision"),
        (lambda c: c["decision"].update(offset="big"), "decision.offset: the decision"),
        (lambda c: c["decision"].update(offset=10**400), "decision.offset: the decision"),
    ],
)
def test_a_model_json_with_numbers_beyond_reason_is_refused(edit, says, short, random_flownet_dir,
                                                            capsys):  # fmt: skip
    # a head of 1e9 hidden channels asked PyTorch for 40 GB; an offset of NaN predicted nonsense
    # with exit 0
    _edit_card(random_flownet_dir, edit)
    code, _, err = run(["evaluate", str(short), "-m", str(random_flownet_dir)], capsys)
    line = one_line(err)
    assert code == 1 and str(random_flownet_dir / "model.json") in line and says in line, line


@pytest.mark.parametrize(
    ("option", "value", "says"),
    [
        ("--people", "100000", "at most 500 at once"),  # asked for 84.6 GiB
        ("--workers", "1000", f"from 1 to {4 * (os.cpu_count() or 1)} processes"),  # forked them
        ("--odom-drift", "1e30", "must be in [0, 1] metres of error per metre driven"),  # exit 0
    ],
)
def test_simulate_refuses_options_beyond_reason(option, value, says, tmp_path, capsys):
    argv = ["simulate", "--frames", "3", "-o", str(tmp_path / "s.npz"), option, value]
    code, _, err = run(argv, capsys)
    line = one_line(err)
    assert code == 1 and option in line and says in line, line
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize("profile", [None, "ros1", "ros2"])
def test_an_mcap_file_of_a_header_alone_says_it_holds_no_message(profile, tmp_path, capsys):
    # the magic alone said `ord() expected a character`; a header record `Profile is not ros2`
    path = tmp_path / "header.mcap"
    header = b"" if profile is None else _mcap_record(0x01, _mcap_string(profile), _mcap_string(""))
    path.write_bytes(MCAP_MAGIC + header)
    code, _, err = run(["info", str(path)], capsys)
    line = one_line(err)
    assert code == 1 and str(path) in line and "holds no ROS message" in line, line
    assert "not a complete MCAP file" in line and "ord()" not in line and "Profile" not in line


@pytest.mark.parametrize(
    ("edit", "says"),
    [
        (lambda a: a.update(angle_min=a["angle_min"][:-1]), "angle_min must be (14,), got (13,)"),
        (lambda a: a.update(offsets=a["offsets"][:-1]), "offsets must be (15,), got (14,)"),
        (lambda a: a.update(ranges=a["ranges"][:-5]), "offsets do not match the ranges array"),
        (
            lambda a: a["angle_increment"].__setitem__(3, 0.0),
            "frame 3: angle_increment is 0 but the scan has more than one beam",
        ),
        (
            lambda a: a["angle_increment"].__setitem__(5, 0.6),
            "frame 5: 768 beams 0.6 rad apart sweep",
        ),
    ],
)
def test_a_recording_with_arrays_that_do_not_fit_is_named(edit, says, short, tmp_path, capsys):
    arrays = dict(np.load(short))
    edit(arrays)
    bad = tmp_path / "bad.npz"
    np.savez(bad, **arrays)
    for argv in (["info", str(bad)], ["evaluate", str(bad), "--baselines-only"]):
        code, _, err = run(argv, capsys)
        line = one_line(err)
        assert code == 1 and f"{bad}: not a usable recording: " in line and says in line, line


@pytest.mark.parametrize(
    ("rate_hz", "says"),
    [
        (1e9, "they step 1 ns apart (1e+09 Hz), faster than any scanner"),  # said 1e9 Hz
        (1e12, "all 20 scans bear one stamp"),  # said 0 Hz
    ],
)
def test_info_says_stamps_that_tell_no_rate_are_unusable(rate_hz, says, tmp_path, capsys):
    # header stamps all 0, so the log times stand in: written 1 ns apart, or all at once
    frames = [np.full(50, 3.0) + 0.01 * i for i in range(20)]
    bag = write_bag(tmp_path / "z.bag", "ros1", {"/scan": frames}, rate_hz=rate_hz,
                    header_stamps=[0] * 20)  # fmt: skip
    code, out, _ = run(["info", str(bag)], capsys)
    assert code == 0 and "frame_rate_hz: unknown" in out, out
    assert f"stamps_unusable: {says}" in out and "the frame rate is unknown" in out, out
    code, out, _ = run(["info", str(bag), "--json"], capsys)
    report = json.loads(out)
    assert report["frame_rate_hz"] is None and says in report["stamps_unusable"]
    code, out, _ = run(["info", str(write_bag(tmp_path / "fine.bag"))], capsys)
    assert "frame_rate_hz: 10.0" in out and "stamps_unusable" not in out, out


@pytest.mark.parametrize("value", [np.nan, np.inf, 0.0, 50.0])  # unknown, no return, out of range
@pytest.mark.parametrize("command", ["predict", "convert"])
def test_scans_without_a_single_return_are_refused(command, value, tmp_path, capsys):
    # wrote blank maps with exit 0 and not a word
    bag = write_bag(tmp_path / "blind.bag", "ros1", {"/scan": [np.full(50, value)] * 14})
    out = tmp_path / ("p.mcap" if command == "predict" else "c.npz")
    code, _, err = run([command, str(bag), "-o", str(out)], capsys)
    line = one_line(err)
    assert code == 1 and f"{bag}: none of its 14 scans has a return" in line, line
    assert not out.exists()


@pytest.mark.parametrize("command", ["predict", "convert"])
def test_scans_mostly_unknown_are_warned_of(command, tmp_path, capsys):
    frames = [np.full(50, np.nan)] * 13 + [np.full(50, 3.0)]
    bag = write_bag(tmp_path / "dim.bag", "ros1", {"/scan": frames})
    out = tmp_path / ("p.mcap" if command == "predict" else "c.npz")
    code, _, err = run([command, str(bag), "-o", str(out)], capsys)
    assert code == 0 and out.exists(), err
    assert "warning: dim.bag: 93% of its beams are invalid" in err, err


def test_train_refuses_data_without_an_occupied_cell(tmp_path, capsys):
    # trained on nothing and reported val_f1 1 (F1's 0/0 convention) with exit 0
    from tests.train.test_cli_train import TINY

    bag = write_bag(tmp_path / "nan.bag", "ros1", {"/scan": [np.full(50, np.nan)] * 30})
    argv = ["train", str(bag), "-o", str(tmp_path / "run"), "--epochs", "1", *TINY]
    code, _, err = run(argv, capsys)
    line = one_line(err)
    assert code == 1 and f"data source {bag}: no occupied cell in any of its" in line, line
    assert "nothing to learn from" in line


@pytest.mark.parametrize("models", [[], ["--baselines-only"]])
def test_ego_oracle_refuses_a_recording_without_poses(models, short, capsys):
    # the "oracle" scored beside the rest with exit 0, told poses nobody had
    code, _, err = run(["evaluate", str(short), "--ego-oracle", *models], capsys)
    line = one_line(err)
    assert code == 1 and f"{short}: --ego-oracle tells models the true next pose" in line, line
    assert "no poses" in line


@pytest.mark.parametrize(
    ("setting", "says"),
    [
        ("model.flow.hidden_channels=1000000000", "hidden_channels must be a whole number in"),
        ("model.flow.dilations=[1,2,100000]", "dilations must be a whole number in [1, 64]"),
        ("model.head.hidden_channels=1000000000", "head_hidden_channels must be a whole number"),
    ],
)
def test_train_refuses_a_model_too_large_to_build(setting, says, short, tmp_path, capsys):
    # PyTorch was asked for 72 GB: an internal error
    recipe = ["--recipe", "head"] if ".head." in setting else []
    argv = ["train", str(short), "-o", str(tmp_path / "run"), "--epochs", "1", *recipe]
    code, _, err = run([*argv, "--set", setting], capsys)
    line = one_line(err)
    assert code == 1 and says in line, line
    assert not (tmp_path / "run").exists()


def test_an_onnx_model_with_an_offset_that_is_no_number_is_refused(flow_onnx, short, tmp_path,
                                                                    capsys):  # fmt: skip
    import onnx

    from lidarflow.predict.backends import DECISION_KEY

    graph = onnx.load(str(flow_onnx))
    for mark in graph.metadata_props:
        if mark.key == DECISION_KEY:
            mark.value = json.dumps({**json.loads(mark.value), "offset": float("nan")})
    bad = tmp_path / "bad.onnx"
    onnx.save(graph, str(bad))
    code, _, err = run(["evaluate", str(short), "-m", str(bad)], capsys)
    line = one_line(err)
    assert code == 1 and f"{bad}: {DECISION_KEY}: the decision offset must be" in line, line
