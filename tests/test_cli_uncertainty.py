"""`lidarflow evaluate` and `predict` with calibration and moving-object segmentation."""

from __future__ import annotations

import json

import pytest

from tests.test_cli import run


def test_help_explains_the_new_options(capsys):
    for command in ("evaluate", "predict"):
        code, text, _ = run([command, "--help"], capsys)
        assert code == 0 and "--moving-threshold" in text
    _, text, _ = run(["evaluate", "--help"], capsys)
    assert "calibration" in text and "segmentation" in text


@pytest.mark.slow
def test_evaluate_on_simulated_data_reports_calibration_and_moving(
    tmp_path, capsys, random_flownet_dir
):
    sim = tmp_path / "sim.npz"
    code, _, err = run(
        ["simulate", "-s", "static", "--frames", "16", "--seed", "0", "-o", str(sim)], capsys
    )
    assert code == 0, err
    out, report = tmp_path / "r", tmp_path / "e.json"
    argv = [
        "evaluate",
        str(sim),
        "-m",
        str(random_flownet_dir),
        "--report",
        str(out),
        "--json",
        str(report),
        "--warmup",
        "2",
        "--gif-frames",
        "3",
        "--moving-threshold",
        "0.3",
    ]
    code, text, err = run(argv, capsys)
    assert code == 0, err
    assert "calibration and moving segmentation" in text and "moving_iou" in text
    result = json.loads(report.read_text())
    methods = result["recordings"][0]["methods"]
    assert {"ece", "ece_active", "brier", "bins"} <= set(methods["copy_last"]["calibration"])
    assert "segmentation" not in methods["copy_last"]
    seg = methods["random_flownet"]["segmentation"]
    assert 0.0 <= seg["iou"] <= 1.0 and seg["frames"] == 16 - 1 - 2
    assert result["config"]["moving_segmentation"]["threshold_cells"] == 0.3
    assert (out / "sim_reliability.png").exists()
    assert (out / "sim_random_flownet_moving.gif").exists()
    page = (out / "index.html").read_text().replace("<wbr>", "")
    assert "moving_iou" in page and "reliability diagram" in page and "moving cells" in page


def test_predict_writes_the_moving_topic(tmp_path, capsys, random_flownet_dir):
    from lidarflow.data import read_bag, sample_bag_path

    rec = tmp_path / "short.npz"
    read_bag(sample_bag_path()).slice(0, 3).save(rec)
    out = tmp_path / "o.mcap"
    code, text, err = run(
        [
            "predict",
            str(rec),
            "-o",
            str(out),
            "-m",
            str(random_flownet_dir),
            "--moving-threshold",
            "0.1",
        ],
        capsys,
    )
    assert code == 0, err
    assert "/lidarflow/moving x3" in text
